// dtif extract <cloud.pcd> [--out trunks.csv] [--repeat n] [--config params.yaml]
#include <time.h>

#include <algorithm>
#include <iostream>
#include <vector>

#include "commands.h"
#include "dtif/core/descriptor/describe.h"
#include "dtif/core/extraction/point_bounds.h"
#include "dtif/io/dataset.h"

namespace dtif::tool {
namespace {

// This thread's CPU time [ms]: the descriptor's cost even when the machine is busy.
double cpuMs() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return 1e3 * static_cast<double>(ts.tv_sec) + 1e-6 * static_cast<double>(ts.tv_nsec);
}

// Describes the cloud n times; prints the min and median thread CPU time of one describe.
void printRepeatedTime(const Cloud& cloud, const DtifParams& params, int n) {
  std::vector<double> ms;
  for (int k = 0; k < n; ++k) {
    const double t0 = cpuMs();
    describeCloud(cloud, SubmapKey{}, params.trunk_extraction, params.descriptor);
    ms.push_back(cpuMs() - t0);
  }
  std::sort(ms.begin(), ms.end());
  std::cout << "  thread CPU time of " << n << " more describes: min " << ms.front()
            << " ms, median " << ms[ms.size() / 2] << " ms\n";
}

}  // namespace

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
  if (a.repeat > 0) printRepeatedTime(*cloud, params, a.repeat);
  if (!a.out.empty()) {
    writeTrunkCsv(a.out, ext.trunks);
    std::cout << "  wrote " << a.out << "\n";
  }
  return 0;
}

}  // namespace dtif::tool
