// dtif bench --speed (bench_speed.cpp): descriptor and query time of this build beside an
// earlier one's, measured by the same speed probe (dtif_query_bench).
#pragma once

#include <filesystem>
#include <ostream>
#include <string>
#include <vector>

namespace dtif::tool {

struct SpeedOptions {
  std::string after_probe;   ///< this build's dtif_query_bench (siblingProbe())
  std::string before_probe;  ///< the earlier build's (scripts/build_before.sh); empty: none
  std::vector<size_t> sizes{1000, 5000, 10000, 20000};  ///< database sizes [entries]
  size_t every = 1;                                     ///< describe every n-th submap
  int repeat = 3;  ///< describes per submap; the fastest counts
};

/// Collects every dataset's descriptors into <dir>/speed_entries.db (by the earlier build when
/// given, which reads no newer file version than its own), measures describe, the
/// protocol's queries and query vs database size with each probe, writes speed_describe.csv,
/// speed_scale.csv and speed_loops_*.txt into dir, and appends the speed tables to md (also
/// returned). Throws std::runtime_error when a probe fails.
std::string appendSpeed(std::ostream& md, const std::filesystem::path& dir,
                        const std::vector<std::string>& datasets, const SpeedOptions& o);

/// dtif_query_bench next to this executable; throws when it is not there.
std::string siblingProbe();

}  // namespace dtif::tool
