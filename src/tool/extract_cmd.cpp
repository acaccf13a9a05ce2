// dtif extract <cloud.pcd> [--out trunks.csv] [--config params.yaml]
#include <chrono>
#include <iostream>

#include "commands.h"
#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/extraction/trunk_extractor.h"
#include "dtif/io/dataset.h"

namespace dtif::tool {

int runExtract(const ExtractArgs& a) {
  const DtifParams params = loadParams(a.configs);
  const std::string& path = a.cloud;
  const Cloud::Ptr cloud = loadPcd(path);

  const auto t0 = std::chrono::steady_clock::now();
  const TrunkExtractionResult ext = extractTrunks(*cloud, params.trunk_extraction);
  const auto t1 = std::chrono::steady_clock::now();
  const Descriptor d = describeSubmap(ext, params.descriptor);
  const auto t2 = std::chrono::steady_clock::now();
  using Ms = std::chrono::duration<double, std::milli>;

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
            << "  time: extraction " << Ms(t1 - t0).count() << " ms, descriptor "
            << Ms(t2 - t1).count() << " ms\n";
  if (!a.out.empty()) {
    writeTrunkCsv(a.out, ext.trunks);
    std::cout << "  wrote " << a.out << "\n";
  }
  return 0;
}

}  // namespace dtif::tool
