// dtif's own PCD reader (issue #17): PCL's PCDReader reads out of bounds on some valid binary
// files (float64 x y z), so every layout is decoded here, after the header is checked.
#pragma once

#include <string>

#include "dtif/core/cloud.h"

namespace dtif {

/// Reads the x y z of a PCD file (DATA ascii, binary or binary_compressed; x, y and z of any
/// numeric TYPE/SIZE, converted to float; other fields skipped). Points with a NaN or infinite
/// coordinate are dropped. Every size is checked against docs/limits.md and the file's length
/// before anything is allocated. Throws DatasetError naming the file (and the line of an ASCII
/// row) on anything malformed. `path` must be a regular file (loadPcd checks that first).
Cloud::Ptr readPcdFile(const std::string& path);

}  // namespace dtif
