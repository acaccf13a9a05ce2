// Files from outside the process (database files, configs, clouds): read only regular files,
// of bounded size, never blocking on a FIFO or reading /dev/zero whole; and written whole or
// not at all (tmp + fsync + rename). docs/limits.md lists the bounds.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace dtif {

/// The problem with reading `path` as a data file, or "": it must exist and be a regular file
/// (not a directory, FIFO, socket or device: checked before opening, so a FIFO never blocks)
/// of at most max_bytes. The problem names neither the path nor the caller's context.
std::string regularFileProblem(const std::string& path, uint64_t max_bytes);

/// The whole of the regular file `path` (regularFileProblem first); throws std::runtime_error
/// "<path>: <problem>" otherwise.
std::vector<uint8_t> readRegularFile(const std::string& path, uint64_t max_bytes);

/// Writes `bytes` to path + ".tmp", fsyncs it, renames it over `path` and fsyncs the folder:
/// after a crash `path` holds the old or the new content, never part of one. Throws
/// std::runtime_error naming the file; the temporary is removed on failure.
void writeFileAtomically(const std::string& path, const std::vector<uint8_t>& bytes);
/// The same for a text.
void writeFileAtomically(const std::string& path, const std::string& text);

/// For files that a library writes itself (a PCD): path + ".tmp", written and closed by the
/// caller, fsynced and renamed over `path`, then the folder fsynced. Throws std::runtime_error
/// naming the file; the temporary is removed on failure.
void replaceWithTemporary(const std::string& path);

/// Removes path + ".tmp" left by a save that a crash interrupted; true when one was removed.
bool removeStaleTemporary(const std::string& path);

}  // namespace dtif
