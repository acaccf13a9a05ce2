#include "dtif/core/extraction/avx2.h"

#include <atomic>

namespace dtif {
namespace {

std::atomic<bool> g_allowed{true};

bool cpuHasAvx2() {
#if DTIF_AVX2_PATHS
  static const bool has = __builtin_cpu_supports("avx2");
  return has;
#else
  return false;
#endif
}

}  // namespace

bool useAvx2() { return cpuHasAvx2() && g_allowed.load(std::memory_order_relaxed); }

void allowAvx2(bool allow) { g_allowed.store(allow, std::memory_order_relaxed); }

}  // namespace dtif
