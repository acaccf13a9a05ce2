// Files of the merged map (DATASET.md, "Merged map"): merged_poses.csv, merged_stems.csv, the
// pose graph as g2o, and field stem maps (CSV x,y[,dbh]) to anchor the map to a plot.
#pragma once

#include <string>
#include <vector>

#include "dtif/core/merge/map_merger.h"

namespace dtif {

/// Reads a field stem map: a CSV whose first columns are x, y[, dbh] in metres, with or without
/// a header line. With a header, columns named x/x_m, y/y_m, dbh/dbh_m are used wherever they
/// are, `tree`/`id`/`stem_id` gives the tree ids (else the 1-based row number) and rows whose
/// `plot_id` differs from `plot` are skipped when `plot` is not empty. Rows with an NA dbh get
/// dbh 0 (unknown). Throws DatasetError naming the file and line on anything else.
std::vector<FieldStem> readStemMapCsv(const std::string& path, const std::string& plot = "");

/// The distinct plot_id values of a stem map file (empty when it has no plot_id column).
std::vector<std::string> stemMapPlots(const std::string& path);

/// merged_poses.csv: id,robot,component,tx,ty,tz,qx,qy,qz,qw (atomic write). Throws
/// DatasetError.
void writeMergedPosesCsv(const std::string& path, const std::vector<MergedPose>& poses);

/// merged_stems.csv: stem_id,component,x,y,z_base,dbh,observations[,field_id] (field_id only
/// when some stem has one; atomic write). Throws DatasetError.
void writeMergedStemsCsv(const std::string& path, const std::vector<MergedStem>& stems);

/// The pose graph in g2o's SE3:QUAT format (VERTEX_SE3:QUAT per submap, EDGE_SE3:QUAT per edge
/// with the upper triangle of its information matrix; atomic write). Throws DatasetError.
void writeG2o(const std::string& path, const std::vector<MergedPose>& poses,
              const std::vector<MergeGraphEdge>& edges);

/// Reads merged_poses.csv back (for scoring a saved map). Throws DatasetError.
std::vector<MergedPose> readMergedPosesCsv(const std::string& path);
/// Reads merged_stems.csv back. Throws DatasetError.
std::vector<MergedStem> readMergedStemsCsv(const std::string& path);

}  // namespace dtif
