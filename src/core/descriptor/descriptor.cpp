// Trunk-topology descriptor (paper Sec. 3.B). This is the only translation unit that includes
// CGAL: its templates are heavy and the rest of the core must not pay for them.
#include "dtif/core/descriptor/descriptor.h"

#include <CGAL/Delaunay_triangulation_2.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Triangulation_vertex_base_with_info_2.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <set>
#include <sstream>
#include <stdexcept>
#include <utility>

#include "core/byte_io.h"
#include "dtif/core/descriptor/validation.h"
#include "dtif/core/extraction/trunk_extractor.h"

namespace dtif {
namespace {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using VertexBase = CGAL::Triangulation_vertex_base_with_info_2<int, Kernel>;
using Tds = CGAL::Triangulation_data_structure_2<VertexBase>;
using Delaunay = CGAL::Delaunay_triangulation_2<Kernel, Tds>;
using CgalPoint = Kernel::Point_2;

/// Trunks whose centres are closer than this are one stem seen twice (or a duplicated input
/// row); keeping both would create a zero-length edge and a sliver face.
constexpr double kDuplicateRadiusM = 0.01;

double dist2d(const TrunkLandmark& a, const TrunkLandmark& b) {
  return std::hypot(a.x - b.x, a.y - b.y);
}

/// Drops non-finite trunks and merges duplicates (centres within kDuplicateRadiusM): the first
/// occurrence is kept, with the mean radius of the group. Output order follows the input order.
Trunks cleanTrunks(const Trunks& in) {
  std::vector<int> order;
  order.reserve(in.size());
  for (size_t i = 0; i < in.size(); ++i) {
    if (finiteTrunk(in[i])) order.push_back(static_cast<int>(i));
  }
  // Sort by x so that duplicates are found in a short window (O(n log n), not O(n^2)).
  std::vector<int> by_x = order;
  std::sort(by_x.begin(), by_x.end(),
            [&](int a, int b) { return in[a].x < in[b].x || (in[a].x == in[b].x && a < b); });
  std::vector<int> owner(in.size(), -1);
  for (size_t i = 0; i < by_x.size(); ++i) {
    const int a = by_x[i];
    if (owner[a] >= 0) continue;
    owner[a] = a;
    for (size_t j = i + 1; j < by_x.size() && in[by_x[j]].x - in[a].x < kDuplicateRadiusM; ++j) {
      const int b = by_x[j];
      if (owner[b] < 0 && dist2d(in[a], in[b]) < kDuplicateRadiusM) owner[b] = a;
    }
  }
  // The group's representative is its smallest input index, so the result does not depend on
  // the sort above.
  std::vector<int> rep(in.size(), -1);
  for (int i : order) {
    const int o = owner[i];
    if (rep[o] < 0 || i < rep[o]) rep[o] = i;
  }
  Trunks out;
  std::vector<int> slot(in.size(), -1);
  std::vector<int> count;
  for (int i : order) {
    const int r = rep[owner[i]];
    if (slot[r] < 0) {
      slot[r] = static_cast<int>(out.size());
      out.push_back(in[r]);
      out.back().r = 0.0;
      out.back().z = 0.0;
      count.push_back(0);
    }
    TrunkLandmark& t = out[slot[r]];
    t.r += in[i].r;
    t.z += in[i].z;
    t.base_seen = t.base_seen && in[i].base_seen;
    ++count[slot[r]];
  }
  for (size_t i = 0; i < out.size(); ++i) {
    out[i].r /= count[i];
    out[i].z /= count[i];
  }
  return out;
}

/// Smallest interior angle of a triangle from its side lengths (law of cosines) [rad].
double minAngle(double a, double b, double c) {
  auto angle = [](double opp, double s1, double s2) {
    const double cosv = (s1 * s1 + s2 * s2 - opp * opp) / (2.0 * s1 * s2);
    return std::acos(std::clamp(cosv, -1.0, 1.0));
  };
  if (a <= 0.0 || b <= 0.0 || c <= 0.0) return 0.0;
  return std::min({angle(a, b, c), angle(b, c, a), angle(c, a, b)});
}

std::vector<float> normalisedHistogram(const std::vector<double>& values, int bins,
                                       double max_value) {
  if (values.empty() || bins <= 0) return {};
  std::vector<float> h(bins, 0.0f);
  for (double v : values) {
    int b = static_cast<int>(std::floor(v / max_value * bins));
    b = std::clamp(b, 0, bins - 1);  // longer/larger values fall in the last bin
    h[b] += 1.0f;
  }
  const float inv = 1.0f / static_cast<float>(values.size());
  for (float& x : h) x *= inv;
  return h;
}

/// Unique edges of the retained faces, for h^e.
std::vector<double> uniqueEdgeLengths(const Trunks& trunks, const std::vector<Triangle>& tris) {
  std::vector<std::pair<int, int>> edges;
  edges.reserve(tris.size() * 3);
  for (const Triangle& t : tris) {
    for (const auto& e : kEdgeEnds) {
      int a = t.v[e[0]], b = t.v[e[1]];
      edges.emplace_back(std::min(a, b), std::max(a, b));
    }
  }
  std::sort(edges.begin(), edges.end());
  edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
  std::vector<double> lens;
  lens.reserve(edges.size());
  for (const auto& e : edges) lens.push_back(dist2d(trunks[e.first], trunks[e.second]));
  return lens;
}

void finishDescriptor(Descriptor& d, const DescriptorParams& params) {
  std::sort(d.triangles.begin(), d.triangles.end(), triangleLess);
  d.edge_hist = normalisedHistogram(uniqueEdgeLengths(d.trunks, d.triangles), params.edge_hist_bins,
                                    params.edge_hist_max_m);
  std::vector<double> radii;
  radii.reserve(d.trunks.size());
  for (const TrunkLandmark& t : d.trunks) radii.push_back(t.r);
  d.radius_hist = normalisedHistogram(radii, params.radius_hist_bins, params.radius_hist_max_m);
}

// ---- wire format helpers ---------------------------------------------------------------------

constexpr uint32_t kMagic = 0x46495444;  // "DTIF" little endian
constexpr uint16_t kVersion = 3;         // 2: base_seen bits; 3: ground map

using detail::fnv1a;  // detects truncated or flipped bytes (radio link and files corrupt data)
using Writer = detail::ByteWriter;
/// Reads a descriptor; running past the end is "descriptor bytes truncated".
struct Reader : detail::ByteReader {
  Reader(const uint8_t* p, size_t n) : detail::ByteReader(p, n, "descriptor bytes") {}
};

}  // namespace

std::string DescriptorParams::validate() const {
  std::ostringstream err;
  if (min_trunks < 3) err << "min_trunks must be >= 3; ";
  if (min_triangles < 1) err << "min_triangles must be >= 1; ";
  if (!std::isfinite(max_edge_m)) err << "max_edge_m must be finite; ";
  if (!(min_angle_deg >= 0.0 && min_angle_deg < 60.0)) err << "min_angle_deg must be in [0, 60); ";
  if (edge_hist_bins < 1 || edge_hist_bins > static_cast<int>(kMaxHistogramBins)) {
    err << "edge_hist_bins must be in [1, " << kMaxHistogramBins << "]; ";
  }
  if (!(edge_hist_max_m > 0.0)) err << "edge_hist_max_m must be > 0; ";
  if (radius_hist_bins < 1 || radius_hist_bins > static_cast<int>(kMaxHistogramBins)) {
    err << "radius_hist_bins must be in [1, " << kMaxHistogramBins << "]; ";
  }
  if (!(radius_hist_max_m > 0.0)) err << "radius_hist_max_m must be > 0; ";
  if (max_bytes < 0) err << "max_bytes must be >= 0 (0: no limit); ";
  return err.str();
}

bool triangleLess(const Triangle& a, const Triangle& b) {
  // len[0] ascending is the matching index; the rest only makes the order total.
  if (a.len[0] != b.len[0]) return a.len[0] < b.len[0];
  if (a.len[1] != b.len[1]) return a.len[1] < b.len[1];
  if (a.len[2] != b.len[2]) return a.len[2] < b.len[2];
  return a.v < b.v;
}

Triangle makeCanonicalTriangle(const Trunks& trunks, int a, int b, int c) {
  // Edges of (u, v, w) = (a, b, c), each with the vertex opposite to it.
  struct Edge {
    double len;
    int p, q;  // endpoints
    int opp;   // opposite vertex
  };
  std::array<Edge, 3> e{{{dist2d(trunks[a], trunks[b]), a, b, c},
                         {dist2d(trunks[b], trunks[c]), b, c, a},
                         {dist2d(trunks[c], trunks[a]), c, a, b}}};
  // Eq. (3.2): sort by decreasing length. Exact ties are broken by the sorted endpoint indices
  // so that the encoding is a pure function of the vertex set (input order does not matter).
  std::sort(e.begin(), e.end(), [](const Edge& x, const Edge& y) {
    if (x.len != y.len) return x.len > y.len;
    const auto kx = std::make_pair(std::min(x.p, x.q), std::max(x.p, x.q));
    const auto ky = std::make_pair(std::min(y.p, y.q), std::max(y.p, y.q));
    return kx < ky;
  });
  Triangle t;
  // I = (e1 ^ e2, e2 ^ e3, e3 ^ e1); the vertex shared by two edges is opposite the third.
  t.v = {e[2].opp, e[0].opp, e[1].opp};
  for (int i = 0; i < 3; ++i) {
    t.len[i] = static_cast<float>(e[i].len);
    t.r[i] = static_cast<float>(trunks[t.v[i]].r);  // Eq. (3.3): radii follow I
  }
  return t;
}

Descriptor describeSubmap(const TrunkExtractionResult& extraction, const DescriptorParams& params) {
  Descriptor d = buildDescriptor(extraction.trunks, params);
  d.footprint = extraction.footprint;
  d.ground_map = extraction.ground_map;
  return d;
}

void fitDescriptorBytes(Descriptor* d, int max_bytes) {
  if (max_bytes <= 0 || d->ground_map.empty()) return;
  const size_t budget = static_cast<size_t>(max_bytes);
  // The rest's bytes without the map (nothing to compress), then the map's own: the map's wire
  // form follows its length, so the two add up.
  GroundMap map = std::move(d->ground_map);
  d->ground_map = GroundMap();
  const size_t rest = encodeDescriptor(*d).size();
  if (rest < budget) d->ground_map = fitGroundMapBytes(std::move(map), budget - rest);
}

bool groundMapFits(const Descriptor& d, int max_bytes) {
  if (max_bytes <= 0) return true;
  if (d.ground_map.empty()) return encodeDescriptor(d).size() < static_cast<size_t>(max_bytes);
  Descriptor rest = d;
  rest.ground_map = GroundMap();
  return encodeDescriptor(rest).size() < static_cast<size_t>(max_bytes);
}

Descriptor buildDescriptor(const Trunks& input, const DescriptorParams& params) {
  Descriptor d;
  const std::string perr = params.validate();
  if (!perr.empty()) {
    d.invalid_reason = "bad descriptor params: " + perr;
    return d;
  }
  d.trunks = cleanTrunks(input);
  const size_t dropped = input.size() - d.trunks.size();
  auto invalid = [&](const std::string& why) {
    d.valid = false;
    d.invalid_reason = why;
    if (dropped > 0) {
      d.invalid_reason +=
          " (" + std::to_string(dropped) + " non-finite or duplicate trunks removed)";
    }
  };
  if (d.trunks.size() > kMaxDescriptorTrunks) {
    // Beyond what a query may cost (docs/limits.md): never inserted, sent or written.
    const size_t n = d.trunks.size();
    d.trunks.clear();
    invalid(std::to_string(n) + " trunks: more than kMaxDescriptorTrunks (" +
            std::to_string(kMaxDescriptorTrunks) + ")");
    return d;
  }
  if (static_cast<int>(d.trunks.size()) < params.min_trunks || d.trunks.size() < 3) {
    finishDescriptor(d, params);
    invalid("too few trunks: " + std::to_string(d.trunks.size()) + " < " +
            std::to_string(params.min_trunks));
    return d;
  }

  // Triangulate in a local frame so that large map coordinates (UTM, 1e5-1e6 m) keep their
  // precision in the inexact constructions; the predicates are exact either way.
  const double ox = d.trunks[0].x, oy = d.trunks[0].y;
  std::vector<std::pair<CgalPoint, int>> pts;
  pts.reserve(d.trunks.size());
  for (size_t i = 0; i < d.trunks.size(); ++i) {
    pts.emplace_back(CgalPoint(d.trunks[i].x - ox, d.trunks[i].y - oy), static_cast<int>(i));
  }
  Delaunay dt;
  dt.insert(pts.begin(), pts.end());
  if (dt.dimension() < 2) {
    finishDescriptor(d, params);
    invalid("collinear trunks: no 2-D triangulation");
    return d;
  }

  const double min_angle = params.min_angle_deg * M_PI / 180.0;
  for (auto f = dt.finite_faces_begin(); f != dt.finite_faces_end(); ++f) {
    const int a = f->vertex(0)->info(), b = f->vertex(1)->info(), c = f->vertex(2)->info();
    Triangle t = makeCanonicalTriangle(d.trunks, a, b, c);
    // Slivers on the hull have unstable shapes between submaps: drop them.
    if (minAngle(t.len[0], t.len[1], t.len[2]) < min_angle) continue;
    if (params.max_edge_m > 0.0 && t.len[0] > params.max_edge_m) continue;
    d.triangles.push_back(t);
  }
  finishDescriptor(d, params);
  if (static_cast<int>(d.triangles.size()) < params.min_triangles) {
    invalid("too few triangles: " + std::to_string(d.triangles.size()) + " < " +
            std::to_string(params.min_triangles));
    return d;
  }
  d.valid = true;
  return d;
}

namespace {

// The trunks, then their base_seen bits.
void putTrunks(const Trunks& trunks, Writer* w) {
  // float32 keeps ~1 mm only within ~10 km of the origin: store offsets from a float64 origin.
  double ox = 0, oy = 0, oz = 0;
  if (!trunks.empty()) {
    ox = trunks[0].x;
    oy = trunks[0].y;
    oz = trunks[0].z;
  }
  w->put<double>(ox);
  w->put<double>(oy);
  w->put<double>(oz);
  w->put<uint16_t>(static_cast<uint16_t>(trunks.size()));
  for (const TrunkLandmark& t : trunks) {
    w->put<float>(static_cast<float>(t.x - ox));
    w->put<float>(static_cast<float>(t.y - oy));
    w->put<float>(static_cast<float>(t.z - oz));
    w->put<float>(static_cast<float>(t.r));
  }
  for (size_t i = 0; i < trunks.size(); i += 8) {
    uint8_t bits = 0;
    for (size_t b = 0; b < 8 && i + b < trunks.size(); ++b)
      bits |= static_cast<uint8_t>(trunks[i + b].base_seen ? 1u << b : 0u);
    w->put<uint8_t>(bits);
  }
}

void putFootprint(const Footprint& f, Writer* w) {
  const bool has_footprint = f.wellFormed();
  w->put<float>(has_footprint ? static_cast<float>(f.cell_m) : 0.0f);
  if (has_footprint) {
    w->put<int32_t>(f.x0);
    w->put<int32_t>(f.y0);
    w->put<uint16_t>(static_cast<uint16_t>(f.width));
    w->put<uint16_t>(static_cast<uint16_t>(f.height));
    for (uint8_t b : f.bits) w->put<uint8_t>(b);
  }
}

}  // namespace

// Layout (little endian):
//   u32 magic, u16 version, u16 flags(bit0 valid), u32 payload bytes, u32 FNV-1a of payload
//   payload: str robot, i64 submap_id, f64 stamp, str invalid_reason,
//            f64 origin x, y, z; u16 n_trunks; n x (f32 dx, dy, dz, r);
//            ceil(n / 8) bytes of base_seen bits (trunk i: byte i / 8, bit i % 8);
//            u32 n_faces; n x u16[3] canonical vertex indices;
//            u8 n_edge_bins, bins x u8; u8 n_radius_bins, bins x u8  (value * 255, rounded);
//            f32 footprint cell (0: none) [, i32 x0, y0; u16 width, height; ceil(w h / 8) bytes];
//            u32 ground map bytes (0: none), encodeGroundMap's bytes;
//            only with flags bit1: f32 qx, qy, qz, qw of the level rotation R_L_S;
//            only with flags bit2 (accumulated): the own trunks, laid out as the trunks
//   (bits 1 and 2 are new in version 3: files without them, older, level or with a
//   submap's own trunks, read as before)
std::vector<uint8_t> encodeDescriptor(const Descriptor& d) {
  // Beyond the bounds a receiver refuses is never written (docs/limits.md: a database file with
  // 300 bins saved and then failed to load).
  if (d.trunks.size() > kMaxDescriptorTrunks || d.own_trunks.size() > kMaxDescriptorTrunks ||
      d.triangles.size() > kMaxFacesPerTrunk * d.trunks.size() ||
      d.edge_hist.size() > kMaxHistogramBins || d.radius_hist.size() > kMaxHistogramBins) {
    throw std::runtime_error("descriptor not encodable: " + checkDescriptor(d));
  }
  Writer w;
  w.putString(d.robot);
  w.put<int64_t>(d.submap_id);
  w.put<double>(d.stamp);
  w.putString(d.invalid_reason);
  putTrunks(d.trunks, &w);
  w.put<uint32_t>(static_cast<uint32_t>(d.triangles.size()));
  for (const Triangle& t : d.triangles) {
    for (int i = 0; i < 3; ++i) w.put<uint16_t>(static_cast<uint16_t>(t.v[i]));
  }
  for (const auto* h : {&d.edge_hist, &d.radius_hist}) {
    w.put<uint8_t>(static_cast<uint8_t>(h->size()));
    for (float x : *h) {
      w.put<uint8_t>(static_cast<uint8_t>(std::lround(std::clamp(x, 0.0f, 1.0f) * 255.0f)));
    }
  }
  putFootprint(d.footprint, &w);
  const std::vector<uint8_t> ground = encodeGroundMap(d.ground_map);
  w.put<uint32_t>(static_cast<uint32_t>(ground.size()));
  w.putBytes(ground);
  if (d.levelled()) {
    const Eigen::Quaterniond q = d.level_rotation.normalized();
    for (double c : {q.x(), q.y(), q.z(), q.w()}) w.put<float>(static_cast<float>(c));
  }
  if (d.accumulated) putTrunks(d.own_trunks, &w);
  Writer out;
  out.put<uint32_t>(kMagic);
  out.put<uint16_t>(kVersion);
  out.put<uint16_t>(
      static_cast<uint16_t>((d.valid ? 1 : 0) | (d.levelled() ? 2 : 0) | (d.accumulated ? 4 : 0)));
  out.put<uint32_t>(static_cast<uint32_t>(w.bytes.size()));
  out.put<uint32_t>(fnv1a(w.bytes.data(), w.bytes.size()));
  out.putBytes(w.bytes);
  return out.bytes;
}

namespace {

/// Checks the header (magic, version, payload size, checksum); returns the payload's reader.
Reader openPayload(const std::vector<uint8_t>& bytes, uint16_t* flags) {
  Reader head(bytes.data(), bytes.size());
  if (head.get<uint32_t>() != kMagic) throw std::runtime_error("not a dtif descriptor (magic)");
  const uint16_t version = head.get<uint16_t>();
  if (version != kVersion) {
    throw std::runtime_error("unsupported descriptor version " + std::to_string(version));
  }
  *flags = head.get<uint16_t>();
  const uint32_t size = head.get<uint32_t>();
  const uint32_t sum = head.get<uint32_t>();
  if (head.remaining() != size) throw std::runtime_error("descriptor payload size mismatch");
  const uint8_t* payload = bytes.data() + (bytes.size() - size);
  if (fnv1a(payload, size) != sum) throw std::runtime_error("descriptor checksum mismatch");
  return Reader(payload, size);
}

/// The float64 origin, the trunks as float32 offsets from it, then their base_seen bits.
void readTrunks(Reader& r, Trunks* trunks) {
  const double ox = r.get<double>(), oy = r.get<double>(), oz = r.get<double>();
  trunks->resize(r.get<uint16_t>());
  for (TrunkLandmark& t : *trunks) {
    t.x = ox + r.get<float>();
    t.y = oy + r.get<float>();
    t.z = oz + r.get<float>();
    t.r = r.get<float>();
  }
  for (size_t i = 0; i < trunks->size(); i += 8) {
    const uint8_t bits = r.get<uint8_t>();
    for (size_t b = 0; b < 8 && i + b < trunks->size(); ++b)
      (*trunks)[i + b].base_seen = (bits >> b) & 1u;
  }
}

/// Vertex triples only: acceptReceivedDescriptor checks them and rebuilds the faces.
void readFaces(Reader& r, std::vector<Triangle>* faces) {
  const uint32_t nf = r.get<uint32_t>();
  if (static_cast<uint64_t>(nf) * 6 > r.remaining()) {
    throw std::runtime_error("descriptor face count exceeds the payload");
  }
  faces->resize(nf);
  for (Triangle& t : *faces) {
    for (int& x : t.v) x = r.get<uint16_t>();
  }
}

/// Quantised bins as read (value / 255); normaliseHistogram undoes the quantisation later.
void readHistogram(Reader& r, std::vector<float>* h) {
  h->resize(r.get<uint8_t>());
  for (float& x : *h) x = r.get<uint8_t>() / 255.0f;
}

void normaliseHistogram(std::vector<float>* h) {
  double total = 0.0;
  for (float x : *h) total += x;
  for (float& x : *h) x = static_cast<float>(x / total);  // undo the quantisation drift
}

/// A cell size of 0 is no footprint; any other (even a bad one, which checkDescriptor
/// rejects) is followed by the bitmap's origin, size and bits.
void readFootprint(Reader& r, Footprint* f) {
  const float cell = r.get<float>();
  if (cell == 0.0f) return;
  f->cell_m = cell;
  f->x0 = r.get<int32_t>();
  f->y0 = r.get<int32_t>();
  f->width = r.get<uint16_t>();
  f->height = r.get<uint16_t>();
  const size_t nbytes = (static_cast<size_t>(f->width) * f->height + 7) / 8;
  if (nbytes > r.remaining()) throw std::runtime_error("descriptor footprint exceeds the payload");
  f->bits.resize(nbytes);
  for (uint8_t& b : f->bits) b = r.get<uint8_t>();
}

void readGroundMap(Reader& r, GroundMap* map) {
  const uint32_t ground_bytes = r.get<uint32_t>();
  if (ground_bytes > r.remaining()) {
    throw std::runtime_error("descriptor ground map exceeds the payload");
  }
  const std::string problem = decodeReceivedGroundMap(r.take(ground_bytes), ground_bytes, map);
  if (!problem.empty()) throw std::runtime_error(problem);
}

// The level rotation, a unit quaternion (float32).
Eigen::Quaterniond readLevelRotation(Reader& r) {
  double c[4];
  for (double& x : c) x = r.get<float>();
  const Eigen::Quaterniond q(c[3], c[0], c[1], c[2]);
  if (!q.coeffs().allFinite() || std::abs(q.norm() - 1.0) > 1e-3) {
    throw std::runtime_error("descriptor level rotation is not a unit quaternion");
  }
  return q.normalized();
}

}  // namespace

Descriptor decodeDescriptor(const std::vector<uint8_t>& bytes, const DescriptorParams& params) {
  uint16_t flags = 0;
  Reader r = openPayload(bytes, &flags);
  Descriptor d;
  d.robot = r.getString();
  d.submap_id = r.get<int64_t>();
  d.stamp = r.get<double>();
  d.invalid_reason = r.getString();
  readTrunks(r, &d.trunks);
  readFaces(r, &d.triangles);
  readHistogram(r, &d.edge_hist);
  readHistogram(r, &d.radius_hist);
  readFootprint(r, &d.footprint);
  readGroundMap(r, &d.ground_map);
  if (flags & 2) d.level_rotation = readLevelRotation(r);
  d.accumulated = (flags & 4) != 0;
  if (d.accumulated) readTrunks(r, &d.own_trunks);
  if (r.remaining() != 0) throw std::runtime_error("descriptor has trailing bytes");
  d.valid = (flags & 1) != 0;
  const std::string problem = acceptReceivedDescriptor(&d, params);
  if (!problem.empty()) throw std::runtime_error(problem);
  normaliseHistogram(&d.edge_hist);
  normaliseHistogram(&d.radius_hist);
  return d;
}

}  // namespace dtif
