// Bounded reads and atomic writes of data files (file_io.h).
#include "dtif/core/file_io.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <stdexcept>

namespace dtif {
namespace {

std::string errnoText() { return std::strerror(errno); }

// Writes all of [p, p + n) to fd; false on an error.
bool writeAll(int fd, const uint8_t* p, size_t n) {
  while (n > 0) {
    const ssize_t k = ::write(fd, p, n);
    if (k < 0 && errno == EINTR) continue;
    if (k <= 0) return false;
    p += k, n -= static_cast<size_t>(k);
  }
  return true;
}

void fsyncFolder(const std::string& path) {
  std::string dir = std::filesystem::path(path).parent_path().string();
  if (dir.empty()) dir = ".";
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY);
  if (fd < 0) return;  // best effort: the file itself is synced
  ::fsync(fd);
  ::close(fd);
}

}  // namespace

std::string regularFileProblem(const std::string& path, uint64_t max_bytes) {
  struct stat st;
  if (::stat(path.c_str(), &st) != 0) return "cannot open: " + errnoText();
  if (S_ISDIR(st.st_mode)) return "is a directory, not a file";
  if (!S_ISREG(st.st_mode)) return "not a regular file (a FIFO, socket or device)";
  if (static_cast<uint64_t>(st.st_size) > max_bytes) {
    return "file of " + std::to_string(st.st_size) + " bytes exceeds the limit of " +
           std::to_string(max_bytes) + " bytes";
  }
  return {};
}

std::vector<uint8_t> readRegularFile(const std::string& path, uint64_t max_bytes) {
  const std::string problem = regularFileProblem(path, max_bytes);
  if (!problem.empty()) throw std::runtime_error(path + ": " + problem);
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) throw std::runtime_error(path + ": cannot open: " + errnoText());
  struct stat st;
  // Checked again on the open file: it may have been replaced since.
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode) ||
      static_cast<uint64_t>(st.st_size) > max_bytes) {
    ::close(fd);
    throw std::runtime_error(path + ": changed while being opened");
  }
  std::vector<uint8_t> buf(static_cast<size_t>(st.st_size));
  size_t got = 0;
  while (got < buf.size()) {
    const ssize_t k = ::read(fd, buf.data() + got, buf.size() - got);
    if (k < 0 && errno == EINTR) continue;
    if (k < 0) {
      const std::string why = errnoText();
      ::close(fd);
      throw std::runtime_error(path + ": read error: " + why);
    }
    if (k == 0) break;  // shrank while reading: what there is
    got += static_cast<size_t>(k);
  }
  ::close(fd);
  buf.resize(got);
  return buf;
}

namespace {

void writeTemporary(const std::string& tmp, const uint8_t* data, size_t size) {
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) throw std::runtime_error(tmp + ": cannot open for writing: " + errnoText());
  const bool ok = writeAll(fd, data, size) && ::fsync(fd) == 0;
  const std::string why = errnoText();
  if (::close(fd) != 0 || !ok) {
    std::remove(tmp.c_str());
    throw std::runtime_error(tmp + ": write failed: " + why);
  }
}

// rename() is atomic on POSIX: readers see the old or the new file, never half of one.
void renameIntoPlace(const std::string& tmp, const std::string& path) {
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    const std::string why = errnoText();
    std::remove(tmp.c_str());
    throw std::runtime_error(path + ": cannot rename " + tmp + " into place: " + why);
  }
  fsyncFolder(path);
}

}  // namespace

void writeFileAtomically(const std::string& path, const std::vector<uint8_t>& bytes) {
  writeTemporary(path + ".tmp", bytes.data(), bytes.size());
  renameIntoPlace(path + ".tmp", path);
}

void writeFileAtomically(const std::string& path, const std::string& text) {
  writeTemporary(path + ".tmp", reinterpret_cast<const uint8_t*>(text.data()), text.size());
  renameIntoPlace(path + ".tmp", path);
}

void replaceWithTemporary(const std::string& path) {
  const std::string tmp = path + ".tmp";
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CLOEXEC);
  const bool ok = fd >= 0 && ::fsync(fd) == 0;
  const std::string why = errnoText();
  if (fd >= 0) ::close(fd);
  if (!ok) {
    std::remove(tmp.c_str());
    throw std::runtime_error(tmp + ": cannot sync: " + why);
  }
  renameIntoPlace(tmp, path);
}

bool removeStaleTemporary(const std::string& path) {
  const std::string tmp = path + ".tmp";
  struct stat st;
  if (::lstat(tmp.c_str(), &st) != 0 || !S_ISREG(st.st_mode)) return false;
  return std::remove(tmp.c_str()) == 0;
}

}  // namespace dtif
