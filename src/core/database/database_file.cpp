// The database file: save/load of every entry's encoded descriptor, atomically written and
// checksummed; read with bounded size and checked entries (docs/limits.md).
#include <cstring>
#include <set>
#include <stdexcept>
#include <utility>

#include "core/byte_io.h"
#include "dtif/core/database/loop_detector.h"
#include "dtif/core/descriptor/validation.h"
#include "dtif/core/file_io.h"

namespace dtif {
namespace {

constexpr char kDbMagic[8] = {'D', 'T', 'I', 'F', 'D', 'B', '\0', '\0'};
constexpr uint32_t kDbVersion = 1;
constexpr size_t kEntryHeaderBytes = 4;

using detail::fnv1a;

// The body's entries (after magic and version, before the checksum); throws on the first
// problem.
std::vector<std::shared_ptr<const Descriptor>> readEntries(detail::ByteReader& r) {
  const uint64_t n = r.get<uint64_t>();
  // Bounded before anything is reserved: every entry takes at least its size field.
  if (n > kMaxDatabaseEntries) {
    throw std::runtime_error(std::to_string(n) + " entries exceed kMaxDatabaseEntries (" +
                             std::to_string(kMaxDatabaseEntries) + ")");
  }
  if (n > r.remaining() / kEntryHeaderBytes) throw std::runtime_error("entry count exceeds file");
  std::vector<std::shared_ptr<const Descriptor>> loaded;
  std::set<std::pair<std::string, int64_t>> keys;
  // The loosest params: keep each descriptor's saved validity.
  const DescriptorParams loose = loosestDescriptorParams();
  for (uint64_t i = 0; i < n; ++i) {
    const uint32_t sz = r.get<uint32_t>();
    if (r.remaining() < sz) throw std::runtime_error("entry truncated");
    const uint8_t* at = r.take(sz);
    auto d =
        std::make_shared<Descriptor>(decodeDescriptor(std::vector<uint8_t>(at, at + sz), loose));
    const std::string entry = "entry " + std::to_string(i);
    if (!d->valid) throw std::runtime_error(entry + " is not valid");
    if (!keys.emplace(d->robot, d->submap_id).second) {
      throw std::runtime_error(entry + " repeats robot '" + d->robot + "' submap " +
                               std::to_string(d->submap_id));
    }
    loaded.push_back(std::move(d));
  }
  if (r.remaining() != 0) throw std::runtime_error("trailing bytes");
  return loaded;
}

}  // namespace

// File layout: 8-byte magic, u32 version, u64 entry count, entries (u32 size + encoded
// descriptor), u32 FNV-1a of everything before it.
void LoopDetector::save(const std::string& path) const {
  detail::ByteWriter w;
  w.bytes.assign(kDbMagic, kDbMagic + 8);
  w.put<uint32_t>(kDbVersion);
  w.put<uint64_t>(entries_.size());
  for (const auto& d : entries_) {
    const std::vector<uint8_t> e = encodeDescriptor(*d);
    w.put<uint32_t>(static_cast<uint32_t>(e.size()));
    w.putBytes(e);
  }
  w.put<uint32_t>(fnv1a(w.bytes.data(), w.bytes.size()));
  if (w.bytes.size() > kMaxDatabaseBytes) {
    throw std::runtime_error(path + ": database of " + std::to_string(w.bytes.size()) +
                             " bytes exceeds kMaxDatabaseBytes: not written");
  }
  writeFileAtomically(path, w.bytes);
}

std::vector<std::shared_ptr<const Descriptor>> readDatabaseFile(const std::string& path) {
  const std::vector<uint8_t> buf = readRegularFile(path, kMaxDatabaseBytes);
  auto fail = [&](const std::string& why) {
    throw std::runtime_error(path + ": not a valid dtif database: " + why);
  };
  if (buf.size() < 8 + 4 + 8 + 4 || std::memcmp(buf.data(), kDbMagic, 8) != 0) fail("bad magic");
  // The body: everything between the magic and the checksum.
  detail::ByteReader r(buf.data() + 8, buf.size() - 8 - 4, "truncated");
  const uint32_t version = r.get<uint32_t>();
  if (version != kDbVersion) {
    fail("version " + std::to_string(version) + ", expected " + std::to_string(kDbVersion));
  }
  uint32_t stored_sum;
  std::memcpy(&stored_sum, buf.data() + buf.size() - 4, 4);
  if (fnv1a(buf.data(), buf.size() - 4) != stored_sum) fail("checksum mismatch");
  try {
    return readEntries(r);
  } catch (const std::exception& e) {  // also length_error / bad_alloc: name the file
    fail(e.what());
  }
  return {};
}

void LoopDetector::load(const std::string& path) { replaceEntries(readDatabaseFile(path)); }

void LoopDetector::replaceEntries(std::vector<std::shared_ptr<const Descriptor>> entries) {
  entries_ = std::move(entries);
  triangles_.assign(entries_.size(), nullptr);
}

}  // namespace dtif
