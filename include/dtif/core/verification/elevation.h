// Elevation (t_z) and residual roll/pitch of a refined loop pose: t_z from the trunk pairs whose
// stem bases were both seen, else from the submaps' ground maps; the tilt is a MAP fit to those
// pairs and, where both submaps carry a ground map, to the maps' cell differences.
#pragma once

#include <utility>
#include <vector>

#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/verification/verification.h"

namespace dtif {

/// Elevation (and, with enough well-spread pairs, residual roll/pitch) of `T` from the pairs
/// whose stem bases were both seen; all pairs vote only when none was. A robust (Tukey) fit of
/// dz = t_z + a x + b y over the pairs, x, y the query trunk in the candidate frame; the plane's
/// slopes are the small rotation left between the two gravity estimates.
/// t_z starts from the mode of the pairs' elevation differences, not their median: in dense
/// understory a "seen" base can sit on a shrub, decimetres high, and when half of a few pairs are
/// wrong a median picks one of them.
/// Returns the RMS elevation residual over the pairs used [m] and fills v's elevation fields:
/// z_pairs, the seen-base pairs that agree with the mode (0: t_z is a guess); z_ambiguity, the
/// largest group of seen-base pairs agreeing on another t_z over the mode's (left as is when
/// no base pair was seen); tilt_fitted, and then roll_var and pitch_var. With pairs that fix t_z
/// the ground maps' cells (VerifierParams::tilt_min_ground_cells) join the tilt fit, each
/// group with its own offset: then the tilt needs no tilt_min_pairs bases
/// (tilt_ground_cells > 0).
double refineElevation(const Descriptor& q, const Descriptor& c,
                       const std::vector<std::pair<int, int>>& pairs, const VerifierParams& params,
                       Pose* T, Verification* v);

/// After refineElevation: with too few agreeing seen-base pairs (min_z_pairs) or disagreeing
/// groups of them (max_z_ambiguity), t_z comes from the ground maps (min_ground_cells), which
/// moves `T` and sets v's T_c_q and ground fields, and fits the residual tilt to the maps' cells
/// (as refineElevation does with bases). Returns why the elevation is not trusted
/// (kElevationUnobserved / kElevationAmbiguous), kNone when it is.
Rejection checkElevation(const Descriptor& q, const Descriptor& c, const VerifierParams& params,
                         Pose* T, Verification* v);

}  // namespace dtif
