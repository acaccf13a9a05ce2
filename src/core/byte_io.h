// Byte buffers of dtif's binary formats (descriptor wire format, ground maps, database files):
// fixed-size values copied in host order (little endian: x86-64, aarch64), length-prefixed
// strings, and the FNV-1a checksum that catches truncated or flipped bytes. Internal to the core.
#pragma once

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

namespace dtif {
namespace detail {

inline uint32_t fnv1a(const uint8_t* p, size_t n) {
  uint32_t h = 2166136261u;
  for (size_t i = 0; i < n; ++i) {
    h ^= p[i];
    h *= 16777619u;
  }
  return h;
}

class ByteWriter {
 public:
  template <class T>
  void put(T v) {
    uint8_t b[sizeof(T)];
    std::memcpy(b, &v, sizeof(T));
    bytes.insert(bytes.end(), b, b + sizeof(T));
  }
  void putString(const std::string& s) {
    const size_t n = std::min<size_t>(s.size(), 65535);
    put<uint16_t>(static_cast<uint16_t>(n));
    bytes.insert(bytes.end(), s.begin(), s.begin() + n);
  }
  void putBytes(const std::vector<uint8_t>& b) { bytes.insert(bytes.end(), b.begin(), b.end()); }
  std::vector<uint8_t> bytes;
};

/// Reads what ByteWriter wrote; running past the end throws "<what> truncated".
class ByteReader {
 public:
  ByteReader(const uint8_t* p, size_t n, const char* what) : p_(p), n_(n), what_(what) {}
  template <class T>
  T get() {
    need(sizeof(T));
    T v;
    std::memcpy(&v, p_ + pos_, sizeof(T));
    pos_ += sizeof(T);
    return v;
  }
  std::string getString() {
    const uint16_t n = get<uint16_t>();
    return std::string(reinterpret_cast<const char*>(take(n)), n);
  }
  /// The next n bytes, in place.
  const uint8_t* take(size_t n) {
    need(n);
    const uint8_t* at = p_ + pos_;
    pos_ += n;
    return at;
  }
  size_t remaining() const { return n_ - pos_; }
  size_t position() const { return pos_; }

 private:
  void need(size_t k) const {
    if (n_ - pos_ < k) throw std::runtime_error(std::string(what_) + " truncated");
  }
  const uint8_t* p_;
  size_t n_;
  const char* what_;
  size_t pos_ = 0;
};

}  // namespace detail
}  // namespace dtif
