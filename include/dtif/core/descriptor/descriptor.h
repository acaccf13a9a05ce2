// Trunk-topology descriptor D = (V, T, h^e, h^r) of paper Sec. 3.B: Delaunay triangulation of
// trunk centres, canonical triangle encoding (Eqs. 3.2-3.3), edge-length and radius histograms.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "dtif/core/extraction/footprint.h"
#include "dtif/core/extraction/ground_map.h"
#include "dtif/core/types.h"

namespace dtif {

struct DescriptorParams {
  int min_trunks = 4;              ///< fewer valid trunks: excluded from retrieval
  int min_triangles = 2;           ///< fewer retained triangles: excluded from retrieval
  double max_edge_m = 25.0;        ///< longest Delaunay edge kept; <= 0 keeps all [m]
  double min_angle_deg = 5.0;      ///< faces with a smaller angle are degenerate [deg]
  int edge_hist_bins = 16;         ///< bins of the edge-length histogram h^e
  double edge_hist_max_m = 16.0;   ///< upper edge of h^e; longer edges fall in the last bin [m]
  int radius_hist_bins = 10;       ///< bins of the radius histogram h^r
  double radius_hist_max_m = 0.5;  ///< upper edge of h^r; larger radii fall in the last bin [m]
  /// The encoded descriptor (about the message on the units' radio link, DESIGN: <= 8 KB) at
  /// most this: the ground map, the one part that can give way, is cropped about its centre to
  /// fit; 0: no limit [bytes]
  int max_bytes = 7800;

  std::string validate() const;

  template <class V>
  void visit(V& v) {
    v("min_trunks", min_trunks);
    v("min_triangles", min_triangles);
    v("max_edge_m", max_edge_m);
    v("min_angle_deg", min_angle_deg);
    v("edge_hist_bins", edge_hist_bins);
    v("edge_hist_max_m", edge_hist_max_m);
    v("radius_hist_bins", radius_hist_bins);
    v("radius_hist_max_m", radius_hist_max_m);
    v("max_bytes", max_bytes);
  }
};

/// A canonically encoded Delaunay face tau = (I_tau, l_tau, r_tau), Eqs. (3.2)-(3.3).
/// len[0] >= len[1] >= len[2]; v = (e1^e2, e2^e3, e3^e1) as trunk indices; r follows v.
/// Canonical edge a has endpoint positions kEdgeEnds[a] into v.
struct Triangle {
  std::array<int, 3> v{};
  std::array<float, 3> len{};
  std::array<float, 3> r{};
};

/// Endpoint positions (into Triangle::v) of canonical edges e1, e2, e3.
constexpr std::array<std::array<int, 2>, 3> kEdgeEnds{{{0, 2}, {0, 1}, {1, 2}}};

/// A submap's descriptor. Immutable once built; safe to share between threads.
struct Descriptor {
  // Identity (filled by the caller; not used by the geometry).
  std::string robot;
  int64_t submap_id = -1;
  double stamp = 0.0;  ///< submap anchor time [s]

  Trunks trunks;                    ///< V
  std::vector<Triangle> triangles;  ///< T, sorted by len[0] ascending (index for matching)
  std::vector<float> edge_hist;     ///< h^e, normalised to sum 1 (empty if no edges)
  std::vector<float> radius_hist;   ///< h^r, normalised to sum 1 (empty if no trunks)
  bool valid = false;               ///< usable for retrieval
  std::string invalid_reason;       ///< why not, when !valid
  /// Occupied cells at trunk height (from extraction; empty for trunk maps such as field
  /// inventories). Lets verification measure the overlap of an aligned pair.
  Footprint footprint;
  /// Lowest point per cell (from extraction, only when few stem bases were seen): fixes the
  /// elevation of a loop that no pair of seen bases fixes. Empty otherwise.
  GroundMap ground_map;
  /// R_L_S: the levelling applied to the submap before extraction (gravity.h). Trunks,
  /// footprint and ground map are in the levelled frame L; identity when the submap was taken
  /// as gravity-aligned (then L = S).
  Eigen::Quaterniond level_rotation = Eigen::Quaterniond::Identity();
  bool levelled() const {
    return level_rotation.coeffs() != Eigen::Quaterniond::Identity().coeffs();
  }
  /// Whether `trunks` were accumulated over several submaps (multi_submap: predecessors'
  /// stems brought in by odometry, one-off fits left out) rather than this submap's own.
  bool accumulated = false;
  /// When accumulated: the submap's own trunks as extraction found them (same frame as
  /// `trunks`). A back end observes trees through them: a predecessor's sighting carried here
  /// by odometry is not this submap's, and as a landmark observation it would tie the submap
  /// to that predecessor along the odometry's drift.
  Trunks own_trunks;
  /// The trunks this submap itself saw: own_trunks when accumulated, else trunks.
  const Trunks& observedTrunks() const { return accumulated ? own_trunks : trunks; }
};

/// Encodes one face canonically from trunk centres (Eq. 3.2) and radii (Eq. 3.3).
Triangle makeCanonicalTriangle(const Trunks& trunks, int a, int b, int c);

/// buildDescriptor's face order: len[0] ascending (the matcher's length index), then len[1],
/// len[2] and v, so that the order is total and does not depend on the input order.
bool triangleLess(const Triangle& a, const Triangle& b);

/// Builds the descriptor of a trunk set. Pure; thread-safe. Too few trunks, collinear or
/// duplicate trunks give an invalid descriptor with a reason, never an exception.
Descriptor buildDescriptor(const Trunks& trunks, const DescriptorParams& params);

struct TrunkExtractionResult;
/// Crops d's ground map until encodeDescriptor(*d) takes at most max_bytes (0: no limit), or
/// drops it when the rest alone does not fit. Called last, once identity and levelling are set.
void fitDescriptorBytes(Descriptor* d, int max_bytes);
/// True when fitDescriptorBytes would keep some of a ground map in d: d without its map takes
/// fewer than max_bytes (0: no limit). Extraction asks this before it builds a map.
bool groundMapFits(const Descriptor& d, int max_bytes);

/// buildDescriptor on an extraction's trunks, with the extraction's footprint and ground map
/// attached (the describe* functions then fit it to params.max_bytes).
Descriptor describeSubmap(const TrunkExtractionResult& extraction, const DescriptorParams& params);

/// Compact wire encoding (what crosses the radio link): trunks as float32, faces as uint16
/// indices, histograms as uint8 quantised. decode(encode(d)) reproduces d up to float32.
std::vector<uint8_t> encodeDescriptor(const Descriptor& d);
/// Throws std::runtime_error on malformed input: a bad header, checksum or layout, or what
/// acceptReceivedDescriptor (validation.h) rejects, with its words. A descriptor valid for its
/// sender but too small for `params` comes back invalid.
Descriptor decodeDescriptor(const std::vector<uint8_t>& bytes, const DescriptorParams& params);

}  // namespace dtif
