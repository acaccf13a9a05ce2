// Checks of received descriptors (wire bytes and ROS messages alike).
#include "dtif/core/descriptor/validation.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace dtif {
namespace {

std::string checkTrunks(const Trunks& trunks) {
  if (trunks.size() > kMaxDescriptorTrunks) {
    return std::to_string(trunks.size()) + " trunks: more than kMaxDescriptorTrunks (" +
           std::to_string(kMaxDescriptorTrunks) + ")";
  }
  for (size_t i = 0; i < trunks.size(); ++i) {
    if (!finiteTrunk(trunks[i])) {
      return "trunk " + std::to_string(i) + " is not finite or has a negative radius";
    }
  }
  return {};
}

std::string checkFaces(const std::vector<Triangle>& faces, size_t n_trunks) {
  if (faces.size() > kMaxFacesPerTrunk * n_trunks) {
    return std::to_string(faces.size()) + " faces: more than a triangulation of " +
           std::to_string(n_trunks) + " trunks has";
  }
  for (size_t f = 0; f < faces.size(); ++f) {
    const std::array<int, 3>& v = faces[f].v;
    for (int i : v) {
      if (i < 0 || static_cast<size_t>(i) >= n_trunks) {
        return "face " + std::to_string(f) + " indexes a missing trunk";
      }
    }
    if (v[0] == v[1] || v[1] == v[2] || v[0] == v[2]) {
      return "face " + std::to_string(f) + " repeats a vertex";
    }
  }
  return {};
}

std::string checkHistogram(const std::vector<float>& h, const std::string& name) {
  if (h.size() > kMaxHistogramBins) {
    return name + " histogram has " + std::to_string(h.size()) +
           " bins: more than kMaxHistogramBins (" + std::to_string(kMaxHistogramBins) + ")";
  }
  double total = 0.0;
  for (float x : h) {
    if (!std::isfinite(x) || x < 0.0f) return name + " histogram is not finite or negative";
    total += x;
  }
  // Normalised to sum 1 when built; all zero cannot be normalised (and matches nothing).
  if (!h.empty() && total <= 0.0) return name + " histogram has no counts";
  return {};
}

}  // namespace

bool finiteTrunk(const TrunkLandmark& t) {
  return std::isfinite(t.x) && std::isfinite(t.y) && std::isfinite(t.z) && std::isfinite(t.r) &&
         t.r >= 0.0;
}

std::string checkDescriptor(const Descriptor& d) {
  std::string problem = checkTrunks(d.trunks);
  if (problem.empty() && !d.own_trunks.empty()) {
    problem = checkTrunks(d.own_trunks);
    if (!problem.empty()) problem = "own trunks: " + problem;
  }
  if (problem.empty()) problem = checkFaces(d.triangles, d.trunks.size());
  if (problem.empty()) problem = checkHistogram(d.edge_hist, "edge");
  if (problem.empty()) problem = checkHistogram(d.radius_hist, "radius");
  if (!problem.empty()) return problem;
  // Verification reads the footprint's and the ground map's cells by their sizes.
  if (d.footprint.cell_m != 0.0 && !d.footprint.wellFormed()) {
    return "footprint is not well formed (cell size, sides or bitmap size)";
  }
  if (d.ground_map.cell_m != 0.0 && !d.ground_map.wellFormed()) {
    return "ground map is not well formed (cell size, sides or cell count)";
  }
  return {};
}

std::string acceptReceivedDescriptor(Descriptor* d, const DescriptorParams& params) {
  const std::string problem = checkDescriptor(*d);
  if (!problem.empty()) return problem;
  for (Triangle& t : d->triangles) t = makeCanonicalTriangle(d->trunks, t.v[0], t.v[1], t.v[2]);
  // The matcher's length index relies on len[0] ascending.
  std::sort(d->triangles.begin(), d->triangles.end(), triangleLess);
  const int n_trunks = static_cast<int>(d->trunks.size());
  const int n_faces = static_cast<int>(d->triangles.size());
  if (d->valid && (n_trunks < params.min_trunks || n_faces < params.min_triangles)) {
    d->valid = false;
    d->invalid_reason = "too few trunks or triangles for the receiver's descriptor params (" +
                        std::to_string(n_trunks) + " trunks, " + std::to_string(n_faces) +
                        " triangles; min_trunks " + std::to_string(params.min_trunks) +
                        ", min_triangles " + std::to_string(params.min_triangles) + ")";
  }
  return {};
}

std::string decodeReceivedGroundMap(const uint8_t* data, size_t size, GroundMap* map) {
  try {
    *map = decodeGroundMap(data, size);
  } catch (const std::exception& e) {
    return std::string("ground map: ") + e.what();
  }
  return {};
}

DescriptorParams loosestDescriptorParams() {
  DescriptorParams p;
  p.min_trunks = 3;
  p.min_triangles = 1;
  return p;
}

}  // namespace dtif
