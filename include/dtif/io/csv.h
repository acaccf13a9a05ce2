// One line of a CSV file split into cells, as every reader of the dataset and merge files
// needs it.
#pragma once

#include <string>
#include <vector>

namespace dtif {

/// The cells of one CSV line: commas inside double quotes do not split (the quotes are
/// dropped), each cell is trimmed of blanks and carriage returns (files written on Windows), a
/// trailing comma gives a last empty cell.
std::vector<std::string> splitCsvLine(const std::string& line);

}  // namespace dtif
