// Issue #17's bombs and bounds (docs/limits.md): database files that are FIFOs, devices,
// directories, huge or repeat an entry; ground-map headers that ask for gigabytes; descriptors
// with more trunks, faces or bins than the limits; saves that leave temporaries behind. Each
// is refused with a message naming the file or the bound, before anything large is allocated.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <stdexcept>

#include "core/loop_test_utils.h"
#include "dtif/core/database/loop_detector.h"
#include "dtif/core/descriptor/validation.h"
#include "dtif/core/extraction/ground_map.h"
#include "dtif/core/file_io.h"
#include "test_utils.h"

namespace dtif {
namespace {

namespace fs = std::filesystem;

// The message of readDatabaseFile's exception ("" when it loads).
std::string loadProblem(const std::string& path) {
  try {
    readDatabaseFile(path);
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "";
}

TEST(Limits, DatabaseFromAFifoIsRefusedWithoutBlocking) {
  const fs::path dir = test::freshTempDir("dtif_limits_fifo");
  const std::string fifo = (dir / "db.fifo").string();
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  // Before the fix this opened the FIFO and blocked for good (no writer ever comes).
  const std::string why = loadProblem(fifo);
  EXPECT_NE(why.find(fifo), std::string::npos) << why;
  EXPECT_NE(why.find("not a regular file"), std::string::npos) << why;
}

TEST(Limits, DatabaseFromADeviceOrFolderIsRefused) {
  // /dev/zero was read whole (without end) before any check.
  EXPECT_NE(loadProblem("/dev/zero").find("not a regular file"), std::string::npos);
  const fs::path dir = test::freshTempDir("dtif_limits_dir");
  EXPECT_NE(loadProblem(dir.string()).find("is a directory"), std::string::npos);
}

TEST(Limits, DatabaseFileOverTheByteLimitIsRefusedUnread) {
  const fs::path dir = test::freshTempDir("dtif_limits_big");
  const std::string big = (dir / "big.db").string();
  { std::ofstream(big, std::ios::binary) << "DTIFDB"; }
  fs::resize_file(big, kMaxDatabaseBytes + 1);  // sparse: no disk space used
  const std::string why = loadProblem(big);
  EXPECT_NE(why.find("exceeds the limit"), std::string::npos) << why;
  EXPECT_NE(why.find(big), std::string::npos) << why;
}

TEST(Limits, DatabaseWithARepeatedEntryIsRefused) {
  const auto cases = test::overlappingPairs(2, 8);
  LoopDetector db{LoopDetectorParams{}};
  const auto d = std::make_shared<Descriptor>(cases[0].c);
  ASSERT_TRUE(db.insert(d));
  ASSERT_TRUE(db.insert(d));  // the detector itself does not dedupe; the file must not load
  const fs::path dir = test::freshTempDir("dtif_limits_dup");
  const std::string path = (dir / "dup.db").string();
  db.save(path);
  const std::string why = loadProblem(path);
  EXPECT_NE(why.find("repeats robot"), std::string::npos) << why;
  LoopDetector other{LoopDetectorParams{}};
  EXPECT_THROW(other.load(path), std::runtime_error);
  EXPECT_EQ(other.size(), 0u);
}

TEST(Limits, SaveLeavesNoTemporaryAndStaleOnesAreRemoved) {
  const auto cases = test::overlappingPairs(2, 8);
  LoopDetector db{LoopDetectorParams{}};
  db.insert(std::make_shared<Descriptor>(cases[0].c));
  const fs::path dir = test::freshTempDir("dtif_limits_tmp");
  const std::string path = (dir / "db.bin").string();
  db.save(path);
  EXPECT_FALSE(fs::exists(path + ".tmp"));
  EXPECT_FALSE(removeStaleTemporary(path));
  { std::ofstream(path + ".tmp") << "half a save"; }  // what kill -9 during a save leaves
  EXPECT_TRUE(removeStaleTemporary(path));
  EXPECT_FALSE(fs::exists(path + ".tmp"));
  LoopDetector other{LoopDetectorParams{}};
  other.load(path);
  EXPECT_EQ(other.size(), 1u);
}

// The text and library-written (PCD) forms of an atomic save: the old content stays whole when
// the new one cannot be put in place, and no temporary is left either way.
TEST(Limits, TextAndLibraryWrittenFilesReplaceTheOldOneWholeOrNotAtAll) {
  const fs::path dir = test::freshTempDir("dtif_limits_text");
  const std::string path = (dir / "ids.csv").string();
  const auto content = [](const std::string& p) {
    std::ifstream f(p);
    return std::string(std::istreambuf_iterator<char>(f), {});
  };
  writeFileAtomically(path, std::string("old\n"));
  writeFileAtomically(path, std::string("id,chain\n1,a\n"));
  EXPECT_EQ(content(path), "id,chain\n1,a\n");
  EXPECT_FALSE(fs::exists(path + ".tmp"));

  { std::ofstream(path + ".tmp") << "written by a library\n"; }
  replaceWithTemporary(path);
  EXPECT_EQ(content(path), "written by a library\n");
  EXPECT_FALSE(fs::exists(path + ".tmp"));
  // Nothing written: the old file stays and the error names the temporary.
  try {
    replaceWithTemporary(path);
    ADD_FAILURE() << "no temporary, yet replaced";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(path + ".tmp"), std::string::npos) << e.what();
  }
  EXPECT_EQ(content(path), "written by a library\n");
  // A folder in the way of the rename: the old content stays, the temporary goes.
  const std::string blocked = (dir / "sub").string();
  fs::create_directories(fs::path(blocked) / "child");
  EXPECT_THROW(writeFileAtomically(blocked, std::string("x")), std::runtime_error);
  EXPECT_TRUE(fs::is_directory(blocked));
  EXPECT_FALSE(fs::exists(blocked + ".tmp"));
}

TEST(Limits, InsertStopsAtMaxDatabaseEntries) {
  const auto cases = test::overlappingPairs(1, 8);
  LoopDetector db{LoopDetectorParams{}};
  const auto d = std::make_shared<Descriptor>(cases[0].c);
  for (size_t i = 0; i < kMaxDatabaseEntries; ++i) ASSERT_TRUE(db.insert(d));
  EXPECT_FALSE(db.insert(d));
  EXPECT_EQ(db.size(), kMaxDatabaseEntries);
}

// A ground map header of 20000 x 20000 cells in an ~800-byte blob made the decoder allocate
// 1.28 GB before the stream was looked at.
TEST(Limits, GroundMapHeaderOverTheSideLimitIsRefusedBeforeAllocating) {
  GroundMap m;
  m.cell_m = 0.5, m.z_step_m = 0.05, m.z0_m = 0.0, m.width = 4, m.height = 3;
  m.z.assign(12, 7);
  std::vector<uint8_t> bytes = encodeGroundMap(m);
  ASSERT_FALSE(bytes.empty());
  const uint16_t side = 20000;
  std::memcpy(bytes.data() + 24, &side, 2);  // width (after 2 f32, f64, 2 i32)
  std::memcpy(bytes.data() + 26, &side, 2);  // height
  try {
    decodeGroundMap(bytes.data(), bytes.size());
    ADD_FAILURE() << "a 20000^2 ground map was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("kMaxGroundMapSide"), std::string::npos) << e.what();
  }
  // Within the side limit but more cells than the stream can inflate to.
  const uint16_t ok_side = kMaxGroundMapSide;
  std::memcpy(bytes.data() + 24, &ok_side, 2);
  std::memcpy(bytes.data() + 26, &ok_side, 2);
  EXPECT_THROW(decodeGroundMap(bytes.data(), bytes.size()), std::runtime_error);
}

// 65535 trunks took a 40 s query; 300 (or 100) histogram bins were accepted and saved.
TEST(Limits, DescriptorsOverTheBoundsAreRefusedAndNeverWritten) {
  const auto cases = test::overlappingPairs(1, 8);
  const Descriptor good = cases[0].c;
  ASSERT_EQ(checkDescriptor(good), "");
  Descriptor many = good;
  many.trunks.resize(65535, good.trunks[0]);
  for (size_t i = 0; i < many.trunks.size(); ++i) many.trunks[i].x += 0.5 * i;
  EXPECT_NE(checkDescriptor(many).find("kMaxDescriptorTrunks"), std::string::npos);
  EXPECT_THROW(encodeDescriptor(many), std::runtime_error);
  for (const size_t bins : {100, 300}) {
    Descriptor wide = good;
    wide.edge_hist.assign(bins, 1.0f / bins);
    EXPECT_NE(checkDescriptor(wide).find("kMaxHistogramBins"), std::string::npos);
    EXPECT_THROW(encodeDescriptor(wide), std::runtime_error);
  }
  Descriptor faces = good;
  faces.triangles.resize(2 * good.trunks.size() + 1, good.triangles[0]);
  EXPECT_NE(checkDescriptor(faces).find("faces"), std::string::npos);
  DescriptorParams p;
  p.edge_hist_bins = 300;
  EXPECT_NE(p.validate().find("edge_hist_bins"), std::string::npos);
  // A built descriptor over the trunk bound is invalid (never inserted), not truncated.
  Trunks t(kMaxDescriptorTrunks + 1);
  for (size_t i = 0; i < t.size(); ++i) t[i].x = static_cast<double>(i % 50), t[i].y = i / 50;
  for (TrunkLandmark& k : t) k.r = 0.1;
  const Descriptor built = buildDescriptor(t, DescriptorParams());
  EXPECT_FALSE(built.valid);
  EXPECT_NE(built.invalid_reason.find("kMaxDescriptorTrunks"), std::string::npos);
}

}  // namespace
}  // namespace dtif
