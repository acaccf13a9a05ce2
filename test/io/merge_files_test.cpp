// Files of the merged map: field stem maps in, merged poses/stems and g2o out.
#include "dtif/io/merge_files.h"

#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

#include "dtif/io/dataset.h"
#include "test_utils.h"

namespace dtif {
namespace {

std::string write(const std::filesystem::path& dir, const std::string& name,
                  const std::string& text) {
  const std::string p = (dir / name).string();
  std::ofstream(p) << text;
  return p;
}

std::string read(const std::string& p) {
  std::ifstream f(p);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

TEST(MergeFiles, StemMapsWithAndWithoutHeader) {
  const auto dir = test::freshTempDir("dtif_merge_files_test");
  const auto plain = readStemMapCsv(write(dir, "a.csv", "1.5,2,0.3\n-3,4\n\n5,6,NA\n"));
  ASSERT_EQ(plain.size(), 3u);
  EXPECT_EQ(plain[0].id, "1");
  EXPECT_DOUBLE_EQ(plain[0].dbh, 0.3);
  EXPECT_DOUBLE_EQ(plain[1].x, -3.0);
  EXPECT_DOUBLE_EQ(plain[1].dbh, 0.0);
  EXPECT_DOUBLE_EQ(plain[2].dbh, 0.0);
  const std::string h = write(dir, "b.csv",
                              "\"x_m\",\"y_m\",\"dbh_m\",\"plot_id\",\"tree\"\n"
                              "1,2,0.2,1,17\n3,4,0.25,2,18\n5,6,0.3,1,19\n");
  const auto plot1 = readStemMapCsv(h, "1");
  ASSERT_EQ(plot1.size(), 2u);
  EXPECT_EQ(plot1[1].id, "19");
  EXPECT_EQ(stemMapPlots(h), (std::vector<std::string>{"1", "2"}));
}

TEST(MergeFiles, BadStemMapsNameTheFileAndLine) {
  const auto dir = test::freshTempDir("dtif_merge_files_test_bad");
  auto expectError = [&](const std::string& text, const std::string& words) {
    const std::string p = write(dir, "bad.csv", text);
    try {
      readStemMapCsv(p);
      ADD_FAILURE() << "no error for " << text;
    } catch (const DatasetError& e) {
      EXPECT_NE(std::string(e.what()).find(p), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
    }
  };
  expectError("", "empty");
  expectError("1,2\n3,x\n", "line 2");
  expectError("1\n", "line 1: too few columns");
  expectError("a,b\n1,2\n", "no x/x_m");
  expectError("1,2,-0.3\n", "negative dbh");
  expectError("1,2,big\n", "dbh must be a number");
  EXPECT_THROW(readStemMapCsv((dir / "missing.csv").string()), DatasetError);
}

TEST(MergeFiles, PosesAndStemsRoundTripAtomically) {
  const auto dir = test::freshTempDir("dtif_merge_files_test_rt");
  MergedPose p;
  p.id = 7;
  p.robot = "alpha";
  p.component = 1;
  p.T_M_S = test::makePose(1.0, -2.0, 0.5, 0.01, -0.02, 1.2);
  const std::string pp = (dir / "merged_poses.csv").string();
  writeMergedPosesCsv(pp, {p});
  EXPECT_FALSE(std::filesystem::exists(pp + ".tmp"));
  EXPECT_EQ(read(pp).substr(0, read(pp).find('\n')), "id,robot,component,tx,ty,tz,qx,qy,qz,qw");
  const auto back = readMergedPosesCsv(pp);
  ASSERT_EQ(back.size(), 1u);
  EXPECT_EQ(back[0].robot, "alpha");
  EXPECT_EQ(back[0].component, 1);
  EXPECT_TRUE(back[0].T_M_S.isApprox(p.T_M_S, 1e-8));

  MergedStem s;
  s.stem_id = 0;
  s.x = 3.25;
  s.y = 4.5;
  s.z_base = -0.25;
  s.dbh = 0.31;
  s.observations = 4;
  const std::string sp = (dir / "merged_stems.csv").string();
  writeMergedStemsCsv(sp, {s});
  EXPECT_EQ(read(sp), "stem_id,component,x,y,z_base,dbh,observations\n0,0,3.25,4.5,-0.25,0.31,4\n");
  s.field_id = "17";
  writeMergedStemsCsv(sp, {s});
  const auto stems = readMergedStemsCsv(sp);
  ASSERT_EQ(stems.size(), 1u);
  EXPECT_EQ(stems[0].field_id, "17");
  EXPECT_EQ(stems[0].observations, 4);

  MergeGraphEdge e;
  e.from = 7;
  e.to = 8;
  e.loop = true;
  const std::string gp = (dir / "graph.g2o").string();
  writeG2o(gp, {p}, {e});
  const std::string g = read(gp);
  EXPECT_EQ(g.rfind("VERTEX_SE3:QUAT 7 ", 0), 0u);
  EXPECT_NE(g.find("EDGE_SE3:QUAT 7 8 0 0 0 0 0 0 1 1 0 0 0 0 0 1"), std::string::npos) << g;
  EXPECT_THROW(writeMergedPosesCsv((dir / "no" / "such" / "dir.csv").string(), {p}), DatasetError);
}

}  // namespace
}  // namespace dtif
