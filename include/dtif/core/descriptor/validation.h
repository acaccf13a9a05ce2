// Checks of a descriptor received from outside the process (wire bytes, a ROS message, a
// database file), in one place: decodeDescriptor and ros_glue::fromMsg both end in
// acceptReceivedDescriptor, so they accept and reject exactly the same descriptors, in the same
// words. All functions are pure and thread-safe.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>

#include "dtif/core/descriptor/descriptor.h"

namespace dtif {

/// Bounds of a descriptor (docs/limits.md). A query's cost grows with the trunks of both
/// sides (65535 trunks took a 40 s query); a submap of a 70 m range sensor in a dense stand
/// (2000 stems/ha) holds about 1000. Beyond: refused at acceptance, never built, sent or saved.
constexpr size_t kMaxDescriptorTrunks = 2000;
/// A Delaunay triangulation of n points has at most 2n - 5 faces.
constexpr size_t kMaxFacesPerTrunk = 2;
/// DescriptorParams' histograms have 16 and 10 bins; the wire format counts them with a uint8.
constexpr size_t kMaxHistogramBins = 64;

/// A finite centre and a finite radius >= 0: what buildDescriptor keeps and the wire carries.
bool finiteTrunk(const TrunkLandmark& t);

/// The first structural problem of a received descriptor, or empty: more trunks than uint16
/// faces can index, a non-finite trunk or negative radius, a face whose vertex index is out of
/// range or repeated, a histogram with more than kMaxHistogramBins bins, a non-finite or
/// negative bin or no counts at all, a footprint or ground map that is not well formed (a cell
/// size of 0 means none). Faces are read by their vertex triples (Triangle::v) only: len and r
/// are rebuilt from the trunks by acceptReceivedDescriptor.
std::string checkDescriptor(const Descriptor& d);

/// Makes a received descriptor usable. checkDescriptor first; then each face is re-encoded
/// from its vertex triple (makeCanonicalTriangle, Eqs. 3.2-3.3, on the received trunks) and
/// the faces are put in buildDescriptor's order (triangleLess), whatever order they came in.
/// Last, a descriptor the sender marked valid but with fewer trunks or faces than the
/// receiver's `params` ask for is marked invalid: not retrievable here, yet not malformed.
/// Returns checkDescriptor's problem (d is then left as it was) or empty.
std::string acceptReceivedDescriptor(Descriptor* d, const DescriptorParams& params);

/// decodeGroundMap for a received descriptor: empty, or the problem as "ground map: <why>"
/// (then *map is unchanged).
std::string decodeReceivedGroundMap(const uint8_t* data, size_t size, GroundMap* map);

/// The receiver's params for a node that builds no descriptors itself (the loop-closure
/// nodelet, database files): the least the matcher can use, 3 trunks and 1 face, so that every
/// descriptor keeps the validity its sender gave it.
DescriptorParams loosestDescriptorParams();

}  // namespace dtif
