// The database file: save/load of every entry's encoded descriptor, atomically written and
// checksummed.
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <stdexcept>

#include "core/byte_io.h"
#include "dtif/core/database/loop_detector.h"
#include "dtif/core/descriptor/validation.h"

namespace dtif {
namespace {

constexpr char kDbMagic[8] = {'D', 'T', 'I', 'F', 'D', 'B', '\0', '\0'};
constexpr uint32_t kDbVersion = 1;

using detail::fnv1a;

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
  const std::vector<uint8_t>& buf = w.bytes;

  const std::string tmp = path + ".tmp";
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    if (!f) throw std::runtime_error(tmp + ": cannot open for writing");
    f.write(reinterpret_cast<const char*>(buf.data()), static_cast<std::streamsize>(buf.size()));
    f.flush();
    if (!f) {
      std::remove(tmp.c_str());
      throw std::runtime_error(tmp + ": write failed");
    }
  }
  // rename() is atomic on POSIX: readers see the old or the new database, never half of one.
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    throw std::runtime_error(path + ": cannot rename " + tmp + " into place");
  }
}

void LoopDetector::load(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw std::runtime_error(path + ": cannot open database file");
  const std::vector<uint8_t> buf((std::istreambuf_iterator<char>(f)),
                                 std::istreambuf_iterator<char>());
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
  // Decode everything into a new list first; the database changes only when all of it is good.
  std::vector<std::shared_ptr<const Descriptor>> loaded;
  try {
    const uint64_t n = r.get<uint64_t>();
    // The loosest params: keep each descriptor's saved validity.
    const DescriptorParams loose = loosestDescriptorParams();
    for (uint64_t i = 0; i < n; ++i) {
      const uint32_t sz = r.get<uint32_t>();
      if (r.remaining() < sz) throw std::runtime_error("entry truncated");
      const uint8_t* at = r.take(sz);
      const std::vector<uint8_t> e(at, at + sz);
      auto d = std::make_shared<Descriptor>(decodeDescriptor(e, loose));
      if (!d->valid) throw std::runtime_error("entry " + std::to_string(i) + " is not valid");
      loaded.push_back(std::move(d));
    }
    if (r.remaining() != 0) throw std::runtime_error("trailing bytes");
  } catch (const std::runtime_error& e) {
    fail(e.what());
  }
  entries_ = std::move(loaded);
  triangles_.assign(entries_.size(), nullptr);
}

}  // namespace dtif
