// Trunk extraction on real third-party data (../shared/data, see its README): radius accuracy
// on 37 mobile-scan trunk slices with field DBH, and trunks found in real MLS/TLS plot clouds.
// Each test skips when the data is absent. Numbers are printed for the benchmarks.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <numeric>
#include <sstream>
#include <string>
#include <vector>

#include "dtif/core/extraction/trunk_extractor.h"
#include "dtif/io/dataset.h"
#include "dtif_test/test_config.h"

namespace dtif {
namespace {

namespace fs = std::filesystem;
const fs::path kData = DTIF_SHARED_DATA_DIR;

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

TEST(RealData, TrunkSliceRadiiAgreeWithFieldDbh) {
  const fs::path index = kData / "trunk_slices" / "index.csv";
  if (!fs::exists(index)) GTEST_SKIP() << "no trunk slices in " << index.parent_path();
  std::ifstream in(index);
  std::string line;
  std::getline(in, line);  // split,tree_id,n_points,approx_x_m,approx_y_m,field_dbh_m
  std::vector<double> abs_err, rel_err;
  int slices = 0, fitted = 0;
  while (std::getline(in, line)) {
    std::stringstream ss(line);
    std::vector<std::string> f;
    for (std::string c; std::getline(ss, c, ',');) f.push_back(c);
    if (f.size() < 6 || f[5].empty()) continue;
    const double dbh = std::stod(f[5]);
    if (!std::isfinite(dbh) || dbh <= 0.0) continue;  // DBH not measured in the field
    const fs::path pcd = kData / "trunk_slices" /
                         (f[0] == "dev" ? "develop_pcds_cropped" : "test_pcds_cropped") /
                         ("tree_" + f[1] + "_main_trunk.pcd");
    if (!fs::exists(pcd)) continue;
    ++slices;
    const Cloud::Ptr cloud = loadPcd(pcd.string());
    std::vector<Eigen::Vector2d> xy;
    for (const auto& p : *cloud) xy.emplace_back(p.x, p.y);
    CircleFitParams cp;  // the extractor's defaults
    const CircleFit fit = fitCircleRobust(xy, cp);
    if (!fit.ok) continue;
    ++fitted;
    abs_err.push_back(std::abs(2.0 * fit.r - dbh));
    rel_err.push_back(std::abs(2.0 * fit.r - dbh) / dbh);
  }
  ASSERT_GT(slices, 0);
  std::printf(
      "[ info ] trunk slices: %d of %d fitted; |DBH error| median %.3f m, mean %.3f m, "
      "median %.1f %% of DBH\n",
      fitted, slices, median(abs_err),
      abs_err.empty() ? 0.0
                      : std::accumulate(abs_err.begin(), abs_err.end(), 0.0) /
                            static_cast<double>(abs_err.size()),
      100.0 * median(rel_err));
  EXPECT_GE(fitted, slices * 9 / 10);
  // The matcher's radius consistency tolerance is 30 %: radii must be well inside it.
  EXPECT_LT(median(rel_err), 0.10);
}

TEST(RealData, TrunksFoundInRealPlotClouds) {
  const fs::path dir = kData / "clouds";
  if (!fs::exists(dir)) GTEST_SKIP() << "no real clouds in " << dir;
  // Stem counts the data's README gives for some plots (approximate).
  const std::vector<std::pair<std::string, int>> known = {
      {"spanner_MLSSparseCloud_xyzOnly", 20}, {"TreeLS_square_2019", 40}, {"TreeLS_pine_plot", 20}};
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(dir))
    if (e.path().extension() == ".pcd") files.push_back(e.path());
  std::sort(files.begin(), files.end());
  ASSERT_FALSE(files.empty());
  for (const fs::path& f : files) {
    const Cloud::Ptr cloud = loadPcd(f.string());
    const TrunkExtractionResult r = extractTrunks(*cloud, TrunkExtractorParams{});
    size_t seen = 0;
    for (const TrunkLandmark& t : r.trunks) seen += t.base_seen;
    std::printf("[ info ] %-32s %8zu points: %3zu trunks (%zu bases seen), %zu candidates\n",
                f.stem().c_str(), cloud->size(), r.trunks.size(), seen, r.stats.candidates);
    for (const auto& [name, stems] : known) {
      if (f.stem() != name) continue;
      EXPECT_GE(static_cast<int>(r.trunks.size()), stems / 2) << name;
      EXPECT_LE(static_cast<int>(r.trunks.size()), 2 * stems) << name;
    }
  }
}

}  // namespace
}  // namespace dtif
