#include "dtif/io/dataset.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <limits>
#include <string>
#include <vector>

#include "dtif/io/csv.h"

namespace dtif {
namespace {

namespace fs = std::filesystem;

class DatasetTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ =
        fs::temp_directory_path() /
        ("dtif_dataset_test_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) +
         "_" + ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  /// A small valid dataset: 3 submaps of 2 robots, ground truth, stems.
  Dataset makeDataset() {
    Dataset ds;
    ds.root = dir_.string();
    for (int i = 0; i < 3; ++i) {
      SubmapRecord r;
      r.id = 10 + i;
      r.robot = i < 2 ? "alpha" : "beta_2";
      r.stamp = 100.25 + 10.0 * i;
      r.file = "submaps/" + std::to_string(r.id) + ".pcd";
      r.T_O_S = Pose::Identity();
      r.T_O_S.translate(Eigen::Vector3d(1.5 * i, -2.0, 0.25));
      r.T_O_S.rotate(Eigen::AngleAxisd(0.3 * i, Eigen::Vector3d::UnitZ()));
      ds.submaps.push_back(r);
      Pose gt = r.T_O_S;
      gt.pretranslate(Eigen::Vector3d(5.0, 6.0, 7.0));
      ds.T_W_S[r.id] = gt;
    }
    ds.stems.push_back({1, 1.0, 2.0, 0.5, 0.3});
    ds.stems.push_back({2, -4.0, 8.5, 0.1, 0.45});
    return ds;
  }

  void writeAll(const Dataset& ds) {
    writeDatasetTables(ds);
    Cloud c;
    c.push_back(pcl::PointXYZ(1.f, 2.f, 3.f));
    c.push_back(pcl::PointXYZ(std::numeric_limits<float>::quiet_NaN(), 0.f, 0.f));
    c.push_back(pcl::PointXYZ(-1.f, 0.5f, 2.f));
    for (const auto& r : ds.submaps) writeSubmapCloud(ds, r, c);
  }

  void writeFile(const std::string& rel, const std::string& text) {
    fs::create_directories((dir_ / rel).parent_path());
    std::ofstream(dir_ / rel) << text;
  }

  /// Expects readDataset to throw a one-line DatasetError mentioning `file` and `what`.
  void expectError(const std::string& file, const std::string& what) {
    try {
      readDataset(dir_.string());
      FAIL() << "expected an error about " << what;
    } catch (const DatasetError& e) {
      const std::string msg = e.what();
      EXPECT_NE(msg.find(file), std::string::npos) << msg;
      EXPECT_NE(msg.find(what), std::string::npos) << msg;
      EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
    }
  }

  fs::path dir_;
};

TEST_F(DatasetTest, WrittenEqualsRead) {
  const Dataset ds = makeDataset();
  writeAll(ds);
  const Dataset back = readDataset(dir_.string());
  ASSERT_EQ(back.submaps.size(), ds.submaps.size());
  for (size_t i = 0; i < ds.submaps.size(); ++i) {
    EXPECT_EQ(back.submaps[i].id, ds.submaps[i].id);
    EXPECT_EQ(back.submaps[i].robot, ds.submaps[i].robot);
    EXPECT_NEAR(back.submaps[i].stamp, ds.submaps[i].stamp, 1e-6);
    EXPECT_EQ(back.submaps[i].file, ds.submaps[i].file);
    EXPECT_TRUE(back.submaps[i].T_O_S.isApprox(ds.submaps[i].T_O_S, 1e-8));
    EXPECT_TRUE(back.T_W_S.at(ds.submaps[i].id).isApprox(ds.T_W_S.at(ds.submaps[i].id), 1e-8));
  }
  ASSERT_EQ(back.stems.size(), 2u);
  EXPECT_EQ(back.stems[1].stem_id, 2);
  EXPECT_DOUBLE_EQ(back.stems[1].x, -4.0);
  EXPECT_DOUBLE_EQ(back.stems[1].dbh, 0.45);
}

TEST_F(DatasetTest, CloudDropsNonFinitePoints) {
  const Dataset ds = makeDataset();
  writeAll(ds);
  const Cloud::Ptr c = loadSubmapCloud(ds, ds.submaps[0]);
  ASSERT_EQ(c->size(), 2u);
  EXPECT_FLOAT_EQ((*c)[0].x, 1.f);
  EXPECT_FLOAT_EQ((*c)[1].z, 2.f);
}

TEST_F(DatasetTest, OptionalFilesMayBeAbsent) {
  Dataset ds = makeDataset();
  ds.T_W_S.clear();
  ds.stems.clear();
  writeAll(ds);
  const Dataset back = readDataset(dir_.string());
  EXPECT_EQ(back.submaps.size(), 3u);
  EXPECT_TRUE(back.T_W_S.empty());
  EXPECT_TRUE(back.stems.empty());
}

TEST_F(DatasetTest, MissingFolderAndSubmapsCsv) {
  expectError(dir_.string(), "no such directory");
  fs::create_directories(dir_);
  expectError("submaps.csv", "missing");
}

TEST_F(DatasetTest, BadRowsAreNamed) {
  const std::string header =
      "id,robot,stamp,file,odom_tx,odom_ty,odom_tz,odom_qx,odom_qy,odom_qz,odom_qw\n";
  writeFile("submaps/1.pcd", "");
  writeFile("submaps.csv",
            header + "1,a,0.0,submaps/1.pcd,0,0,0,0,0,0,1\n1,a,1.0,submaps/1.pcd,0,0,0,0,0,0,1\n");
  expectError("submaps.csv", "duplicate id 1");
  writeFile("submaps.csv", header + "1,bad-name,0.0,submaps/1.pcd,0,0,0,0,0,0,1\n");
  expectError("submaps.csv", "robot name");
  writeFile("submaps.csv", header + "1,a,zero,submaps/1.pcd,0,0,0,0,0,0,1\n");
  expectError("submaps.csv", "'stamp' is not a finite number");
  writeFile("submaps.csv", header + "1,a,nan,submaps/1.pcd,0,0,0,0,0,0,1\n");
  expectError("submaps.csv", "'stamp' is not a finite number");
  writeFile("submaps.csv", header + "1,a,0.0,submaps/2.pcd,0,0,0,0,0,0,1\n");
  expectError("submaps.csv", "does not exist");
  writeFile("submaps.csv", header + "1,a,0.0,submaps/1.pcd,0,0,0,0,0,0,2\n");
  expectError("submaps.csv", "not normalised");
  writeFile("submaps.csv", header + "1,a,0.0,submaps/1.pcd,0,0,0\n");
  expectError("submaps.csv", "too few columns");
  writeFile("submaps.csv", "id,robot,stamp,file\n1,a,0.0,submaps/1.pcd\n");
  expectError("submaps.csv", "missing column 'odom_tx'");
  writeFile("submaps.csv", header);
  expectError("submaps.csv", "no submaps");
  writeFile("submaps.csv", header + "1.5,a,0.0,submaps/1.pcd,0,0,0,0,0,0,1\n");
  expectError("submaps.csv", "not an integer");
}

TEST_F(DatasetTest, GroundTruthMustReferToSubmaps) {
  writeAll(makeDataset());
  writeFile("ground_truth.csv", "id,tx,ty,tz,qx,qy,qz,qw\n99,0,0,0,0,0,0,1\n");
  expectError("ground_truth.csv", "id 99 is not in submaps.csv");
}

TEST_F(DatasetTest, MalformedPcdIsNamed) {
  writeFile("broken.pcd", "this is not a point cloud\n");
  try {
    loadPcd((dir_ / "broken.pcd").string());
    FAIL() << "expected an error";
  } catch (const DatasetError& e) {
    EXPECT_NE(std::string(e.what()).find("broken.pcd"), std::string::npos);
  }
  EXPECT_THROW(loadPcd((dir_ / "absent.pcd").string()), DatasetError);
}

TEST_F(DatasetTest, TruncatedAndInconsistentPcdsAreRejected) {
  const std::string header =
      "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 100\nHEIGHT 1\n"
      "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 100\n";
  writeFile("short.pcd", header + "DATA binary\n" + std::string(40, '\0'));
  writeFile(
      "fields.pcd",
      "VERSION .7\nFIELDS x y z\nSIZE 4 4\nTYPE F F F\nWIDTH 1\nPOINTS 1\nDATA ascii\n1 2 3\n");
  writeFile("data.pcd", header + "DATA zip\n");
  writeFile("noxyz.pcd",
            "VERSION .7\nFIELDS a b\nSIZE 4 4\nTYPE F F\nWIDTH 1\nPOINTS 1\nDATA ascii\n1 2\n");
  writeFile("compressed.pcd", header + "DATA binary_compressed\n" + std::string(8, '\x7f'));
  for (const char* f : {"short.pcd", "fields.pcd", "data.pcd", "noxyz.pcd", "compressed.pcd"}) {
    try {
      loadPcd((dir_ / f).string());
      ADD_FAILURE() << f << " was accepted";
    } catch (const DatasetError& e) {
      EXPECT_NE(std::string(e.what()).find(f), std::string::npos) << e.what();
    }
  }
}

TEST_F(DatasetTest, TrunkCsvWithAndWithoutHeader) {
  writeFile("a.csv", "x,y,z,r\n1,2,0.5,0.2\n3,4,0.1,0.15\n");
  writeFile("b.csv", "1,2,0.5,0.2,extra\n");
  const Trunks a = readTrunkCsv((dir_ / "a.csv").string());
  ASSERT_EQ(a.size(), 2u);
  EXPECT_DOUBLE_EQ(a[1].r, 0.15);
  const Trunks b = readTrunkCsv((dir_ / "b.csv").string());
  ASSERT_EQ(b.size(), 1u);
  EXPECT_DOUBLE_EQ(b[0].z, 0.5);

  Trunks a2 = a;
  a2[1].base_seen = false;
  writeTrunkCsv((dir_ / "c.csv").string(), a2);
  const Trunks c = readTrunkCsv((dir_ / "c.csv").string());
  ASSERT_EQ(c.size(), 2u);
  EXPECT_DOUBLE_EQ(c[0].x, 1.0);
  EXPECT_TRUE(c[0].base_seen);
  EXPECT_FALSE(c[1].base_seen);  // the optional base_seen column round-trips
  writeFile("g.csv", "x,y,z,r,base_seen\n1,2,0.5,0.2,yes\n");
  EXPECT_THROW(readTrunkCsv((dir_ / "g.csv").string()), DatasetError);

  writeFile("d.csv", "x,y,z,r\n1,2,0.5,-0.2\n");
  EXPECT_THROW(readTrunkCsv((dir_ / "d.csv").string()), DatasetError);
  writeFile("e.csv", "x,y,z,r\n1,2,abc,0.2\n");
  EXPECT_THROW(readTrunkCsv((dir_ / "e.csv").string()), DatasetError);
  writeFile("f.csv", "x,y,z,r\n");
  EXPECT_THROW(readTrunkCsv((dir_ / "f.csv").string()), DatasetError);
}

}  // namespace
}  // namespace dtif

namespace dtif {
namespace {

// Issue #17: x y z stored as FLOAT64 (CloudCompare, PDAL), int32 or uint8 were read as float32
// bytes ("114024 finite points", 0 trunks). They are read by their type.
TEST_F(DatasetTest, PcdFieldsOfEveryNumericTypeAreReadByValue) {
  const std::string tail = "WIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA binary\n";
  std::string f64 = "VERSION .7\nFIELDS x y z\nSIZE 8 8 8\nTYPE F F F\nCOUNT 1 1 1\n" + tail;
  for (double v : {1.5, -2.25, 1000.125, 4.0, 5.5, -6.0}) {
    f64.append(reinterpret_cast<const char*>(&v), sizeof(v));
  }
  writeFile("f64.pcd", f64);
  std::string i32 = "VERSION .7\nFIELDS x y z\nSIZE 4 4 1\nTYPE I I U\nCOUNT 1 1 1\n" + tail;
  for (int k = 0; k < 2; ++k) {
    const int32_t x = -7 + k, y = 300000 + k;
    const uint8_t z = static_cast<uint8_t>(200 + k);
    i32.append(reinterpret_cast<const char*>(&x), 4);
    i32.append(reinterpret_cast<const char*>(&y), 4);
    i32.append(reinterpret_cast<const char*>(&z), 1);
  }
  writeFile("i32.pcd", i32);
  const Cloud::Ptr a = loadPcd((dir_ / "f64.pcd").string());
  ASSERT_EQ(a->size(), 2u);
  EXPECT_EQ((*a)[0].x, 1.5f);
  EXPECT_EQ((*a)[0].y, -2.25f);
  EXPECT_EQ((*a)[0].z, 1000.125f);
  EXPECT_EQ((*a)[1].z, -6.0f);
  const Cloud::Ptr b = loadPcd((dir_ / "i32.pcd").string());
  ASSERT_EQ(b->size(), 2u);
  EXPECT_EQ((*b)[1].x, -6.0f);
  EXPECT_EQ((*b)[1].y, 300001.0f);
  EXPECT_EQ((*b)[1].z, 201.0f);
}

// ASCII rows with garbage were read as points; a folder or a FIFO as a cloud gave messages
// that named no file (or blocked); header counts overflowed a signed product.
TEST_F(DatasetTest, GarbageRowsFoldersAndHugeCountsAreRefusedByName) {
  const std::string head =
      "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nPOINTS 2\n";
  writeFile("garbage.pcd", head + "DATA ascii\n1 2 3\n4 five 6\n");
  writeFile("short_row.pcd", head + "DATA ascii\n1 2 3\n4 5\n");
  writeFile("rows.pcd", head + "DATA ascii\n1 2 3\n");
  writeFile("huge.pcd",
            "VERSION .7\nFIELDS x y z\nSIZE 8 8 8\nTYPE F F F\nCOUNT 1 1 1\n"
            "WIDTH 9223372036854775807\nHEIGHT 9223372036854775807\nDATA binary\n");
  writeFile("points.pcd",
            "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
            "WIDTH 1\nPOINTS 99999999999\nDATA binary\n");
  // fuzz_pcd's finding (fuzz/corpus/pcd/fuzz-found-binary-header): NUL and 8-bit bytes in the
  // header made PCL ask for a 100 TB string.
  writeFile("binary_header.pcd", std::string("VERSION .7\nFIELDS x y z int\xd1\0sity\n", 34) +
                                     "SIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH 1\n"
                                     "POINTS 1\nDATA ascii\n1 2 3 4\n");
  fs::create_directories(dir_ / "folder.pcd");
  for (const char* f : {"garbage.pcd", "short_row.pcd", "rows.pcd", "huge.pcd", "points.pcd",
                        "binary_header.pcd", "folder.pcd"}) {
    try {
      loadPcd((dir_ / f).string());
      ADD_FAILURE() << f << " was accepted";
    } catch (const DatasetError& e) {
      EXPECT_NE(std::string(e.what()).find(f), std::string::npos) << e.what();
    }
  }
  EXPECT_THROW(readTrunkCsv((dir_ / "folder.pcd").string()), DatasetError);
  try {  // refused by dtif's header check, before PCL reads it
    loadPcd((dir_ / "binary_header.pcd").string());
  } catch (const DatasetError& e) {
    EXPECT_NE(std::string(e.what()).find("binary bytes in the header"), std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace dtif

namespace dtif {
namespace {

// Issue #17 (UBSan): a cloud of 0 points passed a null reference into PCL's conversion.
TEST_F(DatasetTest, ZeroPointPcdGivesAnEmptyCloud) {
  writeFile("empty.pcd",
            "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 0\nHEIGHT 1\n"
            "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 0\nDATA binary\n");
  EXPECT_TRUE(loadPcd((dir_ / "empty.pcd").string())->empty());
}

TEST(CsvLine, QuotesBlanksCarriageReturnsAndTrailingCommas) {
  using V = std::vector<std::string>;
  EXPECT_EQ(splitCsvLine("id,robot, stamp "), (V{"id", "robot", "stamp"}));
  EXPECT_EQ(splitCsvLine("1,\"a, b\",2\r"), (V{"1", "a, b", "2"}));
  EXPECT_EQ(splitCsvLine("1,,3,"), (V{"1", "", "3", ""}));
  EXPECT_EQ(splitCsvLine("\t7\t"), (V{"7"}));
}

}  // namespace
}  // namespace dtif
