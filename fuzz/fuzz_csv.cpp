// The CSV readers: trunk CSVs (dtif register/score), loop logs, eval results, and a dataset
// folder's tables (the first input byte picks which; the rest is the file).
#include <filesystem>

#include "dtif/io/dataset.h"
#include "fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  const int which = data[0] % 6;
  ++data, --size;
  namespace fs = std::filesystem;
  const fs::path dir = dtif::fuzz::scratchDir() / "dataset";
  try {
    switch (which) {
      case 0:
        dtif::readTrunkCsv(dtif::fuzz::writeInput("trunks.csv", data, size));
        break;
      case 1:
        dtif::readLoopLog(dtif::fuzz::writeInput("loops.csv", data, size));
        break;
      case 2:
        dtif::readAcceptedLoops(dtif::fuzz::writeInput("results.csv", data, size));
        break;
      default: {
        // A dataset whose submaps.csv (3), ground_truth.csv (4) or stems.csv (5) is the input;
        // the other tables are a valid minimal dataset.
        fs::create_directories(dir);
        std::ofstream(dir / "s.pcd") << "";
        std::ofstream(dir / "submaps.csv")
            << "id,robot,stamp,file,odom_tx,odom_ty,odom_tz,odom_qx,odom_qy,odom_qz,odom_qw\n"
               "1,a,1.0,s.pcd,0,0,0,0,0,0,1\n";
        fs::remove(dir / "ground_truth.csv");
        fs::remove(dir / "stems.csv");
        const char* name[] = {"submaps.csv", "ground_truth.csv", "stems.csv"};
        std::ofstream(dir / name[which - 3], std::ios::binary)
            .write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
        dtif::readDataset(dir.string());
      }
    }
  } catch (const dtif::DatasetError&) {
  }
  return 0;
}
