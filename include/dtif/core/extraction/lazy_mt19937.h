// std::mt19937's sequence with its first block of state built only as far as the draws reach.
#pragma once

#include <array>
#include <cstdint>
#include <random>

namespace dtif {

/// Gives the same numbers as std::mt19937(seed), which the standard specifies exactly. The
/// standard engine seeds all 624 words of its state, a serial chain, and twists all 624 at the
/// first draw; a circle RANSAC draws 75-450 numbers per fit. Here word j of the first block is
/// twisted at the j-th draw, from the seed words it reads (j, j + 1 and j + 397, or the
/// already twisted j - 227), seeded just before; later blocks are twisted whole, as std's.
/// A UniformRandomBitGenerator of std::mt19937's result type and range, so a distribution
/// draws from it exactly as from std::mt19937. Not thread-safe; a value type.
class LazyMt19937 {
 public:
  using result_type = std::mt19937::result_type;
  static constexpr result_type min() { return 0; }
  static constexpr result_type max() { return 0xffffffffu; }

  explicit LazyMt19937(uint32_t seed) { x_[0] = seed; }

  /// A uniform index in [0, n) for 0 < n < 2^32, as std::uniform_int_distribution<size_t>(0,
  /// n - 1) draws it from a 32-bit engine in libstdc++ (Lemire's multiply and reject), inline:
  /// the distribution's call per draw cost more than the draw. Tested against it.
  size_t below(uint32_t n) {
    uint64_t product = uint64_t{(*this)()} * n;
    uint32_t low = static_cast<uint32_t>(product);
    if (low < n) {
      const uint32_t threshold = (0u - n) % n;
      while (low < threshold) {
        product = uint64_t{(*this)()} * n;
        low = static_cast<uint32_t>(product);
      }
    }
    return static_cast<size_t>(product >> 32);
  }

  result_type operator()() {
    if (p_ == kN) {
      twistBlock();
    } else if (p_ == twisted_) {
      twistFirstBlockWord();
    }
    uint32_t z = x_[p_++];
    // Tempering, as std::mt19937 (u, d, s, b, t, c, l).
    z ^= z >> 11;
    z ^= (z << 7) & 0x9d2c5680u;
    z ^= (z << 15) & 0xefc60000u;
    z ^= z >> 18;
    return z;
  }

 private:
  static constexpr int kN = 624, kM = 397;

  // Word k twisted with its neighbour k1 and the word km, as std's _M_gen_rand.
  void twist(int k, int k1, int km) {
    const uint32_t y = (x_[k] & 0x80000000u) | (x_[k1] & 0x7fffffffu);
    x_[k] = x_[km] ^ (y >> 1) ^ ((y & 1u) ? 0x9908b0dfu : 0u);
  }
  void twistFirstBlockWord() {
    const int j = twisted_;
    const int need = j < kN - kM ? j + kM + 1 : kN;  // seed words read by words j and j + 1
    for (; seeded_ < need; ++seeded_) {
      const uint32_t prev = x_[seeded_ - 1];
      x_[seeded_] = 1812433253u * (prev ^ (prev >> 30)) + static_cast<uint32_t>(seeded_);
    }
    if (j < kN - kM) {
      twist(j, j + 1, j + kM);
    } else if (j < kN - 1) {
      twist(j, j + 1, j + kM - kN);
    } else {
      twist(j, 0, kM - 1);
    }
    ++twisted_;
  }
  void twistBlock() {
    for (int k = 0; k < kN - kM; ++k) twist(k, k + 1, k + kM);
    for (int k = kN - kM; k < kN - 1; ++k) twist(k, k + 1, k + kM - kN);
    twist(kN - 1, 0, kM - 1);
    p_ = 0;
  }

  std::array<uint32_t, kN> x_;
  int seeded_ = 1;   // seed words written: x_[0] .. x_[seeded_ - 1]
  int twisted_ = 0;  // words of the first block twisted (kN after it)
  int p_ = 0;        // next word to temper and return
};

}  // namespace dtif
