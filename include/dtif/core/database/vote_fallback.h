// The vote fallback (MatcherParams::vote_fallback): when the triangles give no pose hypothesis,
// voted poses fitted to all trunks supply the correspondences instead.
#pragma once

#include <vector>

#include "dtif/core/database/loop_detector.h"

namespace dtif {

/// The voted peaks (votePoses) are fitted to all trunks (fitPose), the best fit must clearly
/// beat every distinct runner-up (repetitive stands give several), and its mutual trunk pairs
/// (unit weights) become the correspondences that the solver and verifyLoop see. Empty with
/// `why` set (kNoVotedPose, kAmbiguousVotes, kFewVotedPairs) when none.
std::vector<Correspondence> voteCorrespondences(const Descriptor& q, const Descriptor& c,
                                                const LoopDetectorParams& params, Rejection* why);

}  // namespace dtif
