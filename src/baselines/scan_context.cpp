// Scan-context-style place recognition baseline (see scan_context.h).
#include "dtif/baselines/scan_context.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <sstream>
#include <stdexcept>

namespace dtif::baselines {

std::string ScanContextParams::validate() const {
  std::ostringstream os;
  if (rings < 1) os << "rings must be >= 1\n";
  if (sectors < 2) os << "sectors must be >= 2\n";
  if (!(max_range_m > 0.0)) os << "max_range_m must be > 0\n";
  if (!(ground_tile_m > 0.0)) os << "ground_tile_m must be > 0\n";
  if (!(ground_percentile >= 0.0 && ground_percentile <= 1.0)) {
    os << "ground_percentile must be in [0, 1]\n";
  }
  if (!(max_height_m > 0.0)) os << "max_height_m must be > 0\n";
  if (min_occupied_bins < 0) os << "min_occupied_bins must be >= 0\n";
  if (candidates < 1) os << "candidates must be >= 1\n";
  if (!(max_distance > 0.0 && max_distance <= 1.0)) os << "max_distance must be in (0, 1]\n";
  return os.str();
}

size_t ScanContext::bytes() const { return (bins.size() + ring_key.size()) * sizeof(float); }

ScanContext makeScanContext(const Cloud& cloud_S, const ScanContextParams& params) {
  const std::string problems = params.validate();
  if (!problems.empty()) throw std::invalid_argument("ScanContextParams: " + problems);
  ScanContext sc;
  sc.rings = params.rings;
  sc.sectors = params.sectors;
  sc.bins.assign(static_cast<size_t>(params.rings) * params.sectors, 0.0f);
  sc.ring_key.assign(params.rings, 0.0f);

  // Local ground: the chosen low quantile of z in each square tile of a grid over the disc.
  // The submaps are gravity-aligned, so a tile's lowest points are its terrain; a tile that
  // holds only canopy or a trunk gets a high ground and thus low bins, which is the price of
  // keeping it per tile.
  const double R = params.max_range_m, tile = params.ground_tile_m;
  const int nt = std::max(1, static_cast<int>(std::ceil(2.0 * R / tile)));
  auto tileOf = [&](double x, double y) {
    const int ix = std::clamp(static_cast<int>(std::floor((x + R) / tile)), 0, nt - 1);
    const int iy = std::clamp(static_cast<int>(std::floor((y + R) / tile)), 0, nt - 1);
    return static_cast<size_t>(iy) * nt + ix;
  };
  auto inRange = [&](const pcl::PointXYZ& p) {
    return std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z) &&
           std::hypot(p.x, p.y) < R;
  };
  std::vector<std::vector<float>> tile_z(static_cast<size_t>(nt) * nt);
  for (const auto& p : cloud_S) {
    if (inRange(p)) tile_z[tileOf(p.x, p.y)].push_back(p.z);
  }
  std::vector<float> ground(tile_z.size(), 0.0f);
  for (size_t t = 0; t < tile_z.size(); ++t) {
    auto& z = tile_z[t];
    if (z.empty()) continue;
    const auto k = static_cast<std::ptrdiff_t>(
        std::floor(params.ground_percentile * static_cast<double>(z.size() - 1)));
    std::nth_element(z.begin(), z.begin() + k, z.end());
    ground[t] = z[k];
    std::vector<float>().swap(z);
  }

  // Bins: the highest point above the local ground (clamped to [0, max_height_m]).
  const double ring_m = R / params.rings, sector_rad = 2.0 * M_PI / params.sectors;
  for (const auto& p : cloud_S) {
    if (!inRange(p)) continue;
    const int ring = std::min(params.rings - 1, static_cast<int>(std::hypot(p.x, p.y) / ring_m));
    const int sector =
        std::min(params.sectors - 1, static_cast<int>((std::atan2(p.y, p.x) + M_PI) / sector_rad));
    const float h = std::clamp(static_cast<float>(p.z - ground[tileOf(p.x, p.y)]), 0.0f,
                               static_cast<float>(params.max_height_m));
    float& bin = sc.bins[static_cast<size_t>(ring) * params.sectors + sector];
    bin = std::max(bin, h);
  }

  // Ring key: mean bin height of each ring, unchanged by any yaw (a column shift).
  int occupied = 0;
  for (int r = 0; r < params.rings; ++r) {
    double sum = 0.0;
    for (int s = 0; s < params.sectors; ++s) {
      const float b = sc.bins[static_cast<size_t>(r) * params.sectors + s];
      sum += b;
      occupied += b > 0.0f;
    }
    sc.ring_key[r] = static_cast<float>(sum / params.sectors);
  }
  if (occupied < params.min_occupied_bins) {
    sc.invalid_reason =
        std::to_string(occupied) + " occupied bins < " + std::to_string(params.min_occupied_bins);
  } else {
    sc.valid = true;
  }
  return sc;
}

namespace {

/// Euclidean norm of each column (one per sector).
std::vector<double> columnNorms(const ScanContext& sc) {
  std::vector<double> n(sc.sectors, 0.0);
  for (int r = 0; r < sc.rings; ++r) {
    for (int s = 0; s < sc.sectors; ++s) {
      const double b = sc.bins[static_cast<size_t>(r) * sc.sectors + s];
      n[s] += b * b;
    }
  }
  for (double& v : n) v = std::sqrt(v);
  return n;
}

bool sameShape(const ScanContext& a, const ScanContext& b) {
  return a.valid && b.valid && a.rings == b.rings && a.sectors == b.sectors && a.rings > 0 &&
         a.sectors > 0;
}

}  // namespace

ScanContextMatch scanContextDistance(const ScanContext& q, const ScanContext& c) {
  ScanContextMatch best;
  if (!sameShape(q, c)) return best;
  const int S = q.sectors;
  const std::vector<double> nq = columnNorms(q), nc = columnNorms(c);
  for (int shift = 0; shift < S; ++shift) {
    double sum = 0.0;
    int used = 0;
    for (int k = 0; k < S; ++k) {
      const int j = (k + shift) % S;
      if (nq[k] <= 0.0 || nc[j] <= 0.0) continue;  // a column empty in either is skipped
      double dot = 0.0;
      for (int r = 0; r < q.rings; ++r) {
        dot += static_cast<double>(q.bins[static_cast<size_t>(r) * S + k]) *
               c.bins[static_cast<size_t>(r) * S + j];
      }
      sum += 1.0 - dot / (nq[k] * nc[j]);
      ++used;
    }
    const double d = used > 0 ? sum / used : 1.0;
    if (d < best.distance) {  // strict: the smallest shift wins ties (deterministic)
      best.distance = d;
      best.shift = shift;
    }
  }
  const int signed_shift = best.shift > S / 2 ? best.shift - S : best.shift;
  best.yaw_rad = 2.0 * M_PI * signed_shift / S;
  return best;
}

double ringKeyDistance(const ScanContext& a, const ScanContext& b) {
  if (!sameShape(a, b)) return std::numeric_limits<double>::infinity();
  double d = 0.0;
  for (int r = 0; r < a.rings; ++r) {
    const double e = static_cast<double>(a.ring_key[r]) - b.ring_key[r];
    d += e * e;
  }
  return d;
}

ScanContextAnswer queryScanContext(const ScanContext& q,
                                   const std::vector<const ScanContext*>& database,
                                   const ScanContextParams& params) {
  ScanContextAnswer answer;
  if (!q.valid) return answer;
  // Ring-key pre-selection: the nearest `candidates` valid entries (ties by position).
  std::vector<std::pair<double, size_t>> keyed;
  for (size_t i = 0; i < database.size(); ++i) {
    if (database[i] && sameShape(q, *database[i])) {
      keyed.emplace_back(ringKeyDistance(q, *database[i]), i);
    }
  }
  const size_t k = std::min(keyed.size(), static_cast<size_t>(params.candidates));
  std::partial_sort(keyed.begin(), keyed.begin() + k, keyed.end());
  for (size_t n = 0; n < k; ++n) {
    const ScanContextMatch m = scanContextDistance(q, *database[keyed[n].second]);
    const auto index = static_cast<int64_t>(keyed[n].second);
    if (answer.index < 0 || m.distance < answer.match.distance ||
        (m.distance == answer.match.distance && index < answer.index)) {
      answer.index = index;
      answer.match = m;
    }
  }
  return answer;
}

}  // namespace dtif::baselines
