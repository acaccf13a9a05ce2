// dtif extract <cloud.pcd> [--out trunks.csv] [--config params.yaml]
#include <iostream>

#include "commands.h"
#include "dtif/core/descriptor/describe.h"
#include "dtif/core/extraction/point_bounds.h"
#include "dtif/io/dataset.h"

namespace dtif::tool {

int runExtract(const ExtractArgs& a) {
  const DtifParams params = loadParams(a.configs);
  const std::string& path = a.cloud;
  const Cloud::Ptr cloud = loadPcd(path);

  DescribeTimings ms;
  TrunkExtractionResult ext;
  const Descriptor d =
      describeCloud(*cloud, SubmapKey{}, params.trunk_extraction, params.descriptor, &ms, &ext);

  const std::string warning = boundsWarning(ext.stats, params.trunk_extraction);
  if (!warning.empty()) std::cerr << path << ": warning: " << warning << "\n";
  std::cout << path << ": " << ext.stats.finite_points << " finite points of "
            << ext.stats.input_points << "\n"
            << "  trunks: " << ext.trunks.size() << " (candidates " << ext.stats.candidates
            << ", rejected fit " << ext.stats.rejected_fit << ", leaning "
            << ext.stats.rejected_lean << ", duplicates " << ext.stats.duplicates
            << ", bases not seen " << ext.stats.unseen_bases << ")\n"
            << "  Delaunay faces: " << d.triangles.size() << "\n"
            << "  descriptor: "
            << (d.valid ? "valid" : "excluded from retrieval: " + d.invalid_reason) << ", "
            << encodeDescriptor(d).size() << " bytes\n"
            << "  time: extraction " << ms.extract_ms << " ms, descriptor "
            << ms.total_ms - ms.extract_ms << " ms\n";
  if (!a.out.empty()) {
    writeTrunkCsv(a.out, ext.trunks);
    std::cout << "  wrote " << a.out << "\n";
  }
  return 0;
}

}  // namespace dtif::tool
