// dtif's own PCD reader (issue #17): every layout PCL writes, fields of any numeric type read by
// value, malformed data refused naming the file (and the line of an ASCII row).
#include "dtif/io/pcd_reader.h"

#include <gtest/gtest.h>
#include <pcl/io/pcd_io.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>

#include "dtif/io/dataset.h"
#include "test_utils.h"

namespace dtif {
namespace {

namespace fs = std::filesystem;

class PcdReaderTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = test::freshTempDir(std::string("dtif_pcd_reader_test_") +
                              ::testing::UnitTest::GetInstance()->current_test_info()->name());
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string write(const std::string& name, const std::string& bytes) const {
    const std::string path = (dir_ / name).string();
    std::ofstream(path, std::ios::binary) << bytes;
    return path;
  }
  static std::string read(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
  }
  template <typename T>
  static void put(std::string& s, T v) {
    s.append(reinterpret_cast<const char*>(&v), sizeof(v));
  }
  /// loadPcd's error for a file that must be refused (a failure if it is read).
  static std::string refusal(const std::string& path) {
    try {
      loadPcd(path);
      ADD_FAILURE() << path << " was accepted";
    } catch (const DatasetError& e) {
      EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
      return e.what();
    }
    return "";
  }

  fs::path dir_;
};

std::string header(const std::string& fields, const std::string& size, const std::string& type,
                   const std::string& count, int points, const std::string& data) {
  return "VERSION 0.7\nFIELDS " + fields + "\nSIZE " + size + "\nTYPE " + type + "\nCOUNT " +
         count + "\nWIDTH " + std::to_string(points) + "\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n" +
         "POINTS " + std::to_string(points) + "\nDATA " + data + "\n";
}

// fuzz_pcd's open finding (fuzz/corpus/pcd/f64.pcd): PCL's PCDReader::read read out of bounds on
// this valid file (float64 x y z, a uint8 after them, exactly the data length), and a release
// build ended in std::bad_alloc. Read by dtif, every coordinate is exact.
TEST_F(PcdReaderTest, Float64XyzBeforeAUint8FieldAreReadExactly) {
  std::string f = header("x y z intensity", "8 8 8 1", "F F F U", "1 1 1 1", 2, "binary");
  const double v[2][3] = {{1.5, -2.25, 1000.125}, {4.0, 5.5, -6.0}};
  for (const auto& p : v) {
    for (double c : p) put(f, c);
    put(f, uint8_t{7});
  }
  const Cloud::Ptr c = loadPcd(write("f64.pcd", f));
  ASSERT_EQ(c->size(), 2u);
  for (int i = 0; i < 2; ++i) {
    EXPECT_EQ((*c)[i].x, static_cast<float>(v[i][0]));
    EXPECT_EQ((*c)[i].y, static_cast<float>(v[i][1]));
    EXPECT_EQ((*c)[i].z, static_cast<float>(v[i][2]));
  }
}

// fuzz_pcd's reproducer (fuzz/corpus/pcd/fuzz-found-pcl-columns): binary data that happen to
// begin with the bytes "COLUMNS" (PCL's old name of FIELDS) made PCL's PCDReader::read read
// out of bounds (SEGV under ASan; std::bad_alloc in a release build, so the valid file was
// refused). Binary data are bytes: dtif reads them as the header says.
TEST_F(PcdReaderTest, BinaryDataThatSpellAHeaderKeywordAreData) {
  std::string data = "COLUMNS";
  for (int i = 0; i < 17; ++i) data.push_back(static_cast<char>(i * 13));
  float v[6];
  std::memcpy(v, data.data(), sizeof(v));
  const Cloud::Ptr c =
      loadPcd(write("columns.pcd", header("x y z", "4 4 4", "F F F", "1 1 1", 2, "binary") + data));
  ASSERT_EQ(c->size(), 2u);
  for (int i = 0; i < 2; ++i) {
    EXPECT_EQ((*c)[i].x, v[3 * i]);
    EXPECT_EQ((*c)[i].y, v[3 * i + 1]);
    EXPECT_EQ((*c)[i].z, v[3 * i + 2]);
  }
}

// Integer x y z (int32, uint8, int16; int64, uint64) between fields of COUNT > 1, which are
// skipped by their layout, in binary and in ASCII.
TEST_F(PcdReaderTest, IntegerFieldsAndFieldsOfCountAboveOneAreReadByLayout) {
  const std::string fields = "normal x y z rgb", size = "4 4 1 2 4", type = "F I U I U",
                    count = "3 1 1 1 2";
  std::string bin = header(fields, size, type, count, 2, "binary");
  std::string asc = header(fields, size, type, count, 2, "ascii");
  for (int k = 0; k < 2; ++k) {
    for (float n : {0.5f, -0.5f, 9.f}) put(bin, n);
    put(bin, int32_t{-7 + k});
    put(bin, static_cast<uint8_t>(200 + k));
    put(bin, static_cast<int16_t>(-300 - k));
    put(bin, uint32_t{1});
    put(bin, uint32_t{2});
    asc += "0.5 -0.5 9 " + std::to_string(-7 + k) + " " + std::to_string(200 + k) + " " +
           std::to_string(-300 - k) + " 1 2\n";
  }
  for (const std::string& path : {write("bin.pcd", bin), write("asc.pcd", asc)}) {
    const Cloud::Ptr c = loadPcd(path);
    ASSERT_EQ(c->size(), 2u) << path;
    EXPECT_EQ((*c)[1].x, -6.f) << path;
    EXPECT_EQ((*c)[1].y, 201.f) << path;
    EXPECT_EQ((*c)[1].z, -301.f) << path;
    EXPECT_EQ((*c)[0].x, -7.f) << path;
  }
  std::string wide = header("x pad y z", "8 2 8 4", "I U U F", "1 1 1 1", 1, "binary");
  put(wide, int64_t{-123456});
  put(wide, uint16_t{0});
  put(wide, uint64_t{1} << 40);
  put(wide, 0.25f);
  const Cloud::Ptr w = loadPcd(write("wide.pcd", wide));
  ASSERT_EQ(w->size(), 1u);
  EXPECT_EQ((*w)[0].x, -123456.f);
  EXPECT_EQ((*w)[0].y, static_cast<float>(uint64_t{1} << 40));
  EXPECT_EQ((*w)[0].z, 0.25f);
}

// binary_compressed as PCL's writer stores it (LZF, the fields one after the other): float32
// with a NaN point (dropped), and float64 x y z with a uint8 field.
TEST_F(PcdReaderTest, CompressedFilesOfPclsWriterAreRead) {
  pcl::PointCloud<pcl::PointXYZI> a;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int i = 0; i < 300; ++i) {
    pcl::PointXYZI p;
    p.x = 0.5f * i;
    p.y = -1.25f * (i % 7);
    p.z = i == 17 ? nan : 3.f + 0.001f * i;
    p.intensity = static_cast<float>(i);
    a.push_back(p);
  }
  const std::string fa = (dir_ / "xyzi.pcd").string();
  ASSERT_EQ(pcl::io::savePCDFileBinaryCompressed(fa, a), 0);
  const Cloud::Ptr ca = loadPcd(fa);
  ASSERT_EQ(ca->size(), 299u);
  for (size_t i = 0, j = 0; i < a.size(); ++i) {
    if (i == 17) continue;
    EXPECT_EQ((*ca)[j].x, a[i].x);
    EXPECT_EQ((*ca)[j].y, a[i].y);
    EXPECT_EQ((*ca)[j++].z, a[i].z);
  }

  pcl::PCLPointCloud2 b;
  b.width = 5;
  b.height = 1;
  b.point_step = 25;
  for (uint32_t k = 0; k < 4; ++k) {
    pcl::PCLPointField f;
    f.name = k < 3 ? std::string(1, "xyz"[k]) : "intensity";
    f.offset = 8 * k;
    f.datatype = k < 3 ? pcl::PCLPointField::FLOAT64 : pcl::PCLPointField::UINT8;
    f.count = 1;
    b.fields.push_back(f);
  }
  b.data.resize(b.width * b.point_step);
  for (uint32_t i = 0; i < b.width; ++i) {
    for (uint32_t k = 0; k < 3; ++k) {
      const double v = 100.0 * k + 1.5 * i - 2.0;
      std::memcpy(&b.data[i * b.point_step + 8 * k], &v, 8);
    }
    b.data[i * b.point_step + 24] = static_cast<uint8_t>(i);
  }
  const std::string fb = (dir_ / "f64c.pcd").string();
  ASSERT_EQ(pcl::PCDWriter().writeBinaryCompressed(fb, b), 0);
  ASSERT_NE(read(fb).find("DATA binary_compressed"), std::string::npos);
  const Cloud::Ptr cb = loadPcd(fb);
  ASSERT_EQ(cb->size(), 5u);
  for (uint32_t i = 0; i < 5; ++i) {
    EXPECT_EQ((*cb)[i].x, static_cast<float>(1.5 * i - 2.0));
    EXPECT_EQ((*cb)[i].y, static_cast<float>(100.0 + 1.5 * i - 2.0));
    EXPECT_EQ((*cb)[i].z, static_cast<float>(200.0 + 1.5 * i - 2.0));
  }
}

// A corrupt LZF stream, a block cut short, and a block that claims more than LZF can expand
// to (refused before the output is allocated).
TEST_F(PcdReaderTest, CorruptOrShortCompressedBlocksAreRefusedByName) {
  pcl::PointCloud<pcl::PointXYZ> a;
  for (int i = 0; i < 100; ++i) a.push_back({0.1f * i, 2.f, 3.f});
  const std::string good = (dir_ / "good.pcd").string();
  ASSERT_EQ(pcl::io::savePCDFileBinaryCompressed(good, a), 0);
  const std::string bytes = read(good);
  const size_t data = bytes.find("DATA binary_compressed\n") + 23;
  std::string corrupt = bytes;
  corrupt[data + 8] = '\xff';  // a back reference before the start of the output
  EXPECT_NE(refusal(write("corrupt.pcd", corrupt)).find("do not decode"), std::string::npos);
  const std::string cut = bytes.substr(0, bytes.size() - 5);
  EXPECT_NE(refusal(write("cut.pcd", cut)).find("truncated"), std::string::npos);

  std::string huge = header("x y z", "4 4 4", "F F F", "1 1 1", 1000000, "binary_compressed");
  put(huge, uint32_t{16});
  put(huge, uint32_t{12000000});
  huge += std::string(16, '\0');
  EXPECT_NE(refusal(write("huge.pcd", huge)).find("cannot hold"), std::string::npos);
}

// Garbage in an ASCII row is refused naming the file and the line; NaN and infinite points are
// dropped as in the other layouts.
TEST_F(PcdReaderTest, AsciiGarbageNamesTheLineAndNonFinitePointsAreDropped) {
  const std::string head = header("x y z", "4 4 4", "F F F", "1 1 1", 4, "ascii");
  const std::string ok = head + "1 2 3\nnan 1 1\n\n4 inf 6\n7 8 9\n";
  const Cloud::Ptr c = loadPcd(write("ok.pcd", ok));
  ASSERT_EQ(c->size(), 2u);
  EXPECT_EQ((*c)[1].x, 7.f);
  // The header is 10 lines: the bad row is line 12 of the file.
  const std::string m = refusal(write("bad.pcd", head + "1 2 3\n4 5x 6\n7 8 9\n1 1 1\n"));
  EXPECT_NE(m.find("line 12"), std::string::npos) << m;
  EXPECT_NE(m.find("'5x' is not a number"), std::string::npos) << m;
  refusal(write("nul.pcd", head + "1 2 3\n4 5" + std::string(1, '\0') + " 6\n7 8 9\n1 1 1\n"));
  refusal(write("comma.pcd", head + "1 2 3\n4,5,6\n7 8 9\n1 1 1\n"));
  refusal(write("extra.pcd", head + "1 2 3\n4 5 6\n7 8 9\n1 1 1\n2 2 2\n"));
}

// Binary data one byte short, and a header whose WIDTH x HEIGHT disagrees with POINTS.
TEST_F(PcdReaderTest, TruncatedBinaryAndInconsistentCountsAreRefused) {
  std::string f = header("x y z", "8 8 8", "F F F", "1 1 1", 3, "binary");
  for (int i = 0; i < 9; ++i) put(f, 1.0 * i);
  EXPECT_EQ(loadPcd(write("full.pcd", f))->size(), 3u);
  f.pop_back();
  EXPECT_NE(refusal(write("short.pcd", f)).find("truncated"), std::string::npos);
  std::string wh =
      "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nHEIGHT 2\n"
      "POINTS 3\nDATA ascii\n1 2 3\n1 2 3\n1 2 3\n";
  EXPECT_NE(refusal(write("wh.pcd", wh)).find("WIDTH x HEIGHT"), std::string::npos);
  std::string xcount = header("x y z", "4 4 4", "F F F", "2 1 1", 1, "ascii") + "1 2 3 4\n";
  EXPECT_NE(refusal(write("xcount.pcd", xcount)).find("'x'"), std::string::npos);
}

}  // namespace
}  // namespace dtif
