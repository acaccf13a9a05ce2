// All of dtif's parameters and their YAML form (one section per component, see config/*.yaml).
#pragma once

#include <string>

#include "dtif/core/database/loop_detector.h"
#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/descriptor/trunk_accumulator.h"
#include "dtif/core/extraction/gravity.h"
#include "dtif/core/extraction/trunk_extractor.h"
#include "dtif/core/merge/map_merger.h"
#include "dtif/core/params.h"

namespace dtif {

struct DtifParams {
  TrunkExtractorParams trunk_extraction;  ///< YAML section `trunk_extraction`
  LevellingParams levelling;              ///< YAML section `levelling` (gravity.h)
  DescriptorParams descriptor;            ///< YAML section `descriptor`
  MultiSubmapParams multi_submap;         ///< YAML section `multi_submap` (very sparse stands)
  LoopDetectorParams loop;  ///< sections `matcher`, `pose`, `verification`, `database`
  MergeParams merge;        ///< sections `merge` and `stems` (the map merger, map_merger.h)

  /// Empty when every component validates, else the problems, one per line.
  std::string validate() const;
};

/// Reads a YAML file holding any subset of the sections and overrides those values in *p.
/// Unknown sections or keys, wrong types and invalid values throw ParamError naming the file.
void loadParamsYaml(const std::string& path, DtifParams* p);

/// The YAML text of all parameters (the effective configuration, for logs and results).
std::string paramsToYaml(const DtifParams& p);

}  // namespace dtif
