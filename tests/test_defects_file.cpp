// The defects file (vision/RECORDING.md "The defects file"): the same points as CSV and as
// PLY give the same clusters, and every refusal names the file, the line and what is wrong.
#include <catch2/catch.hpp>

#include <cmath>

#include "markcell/control/marking.hpp"
#include "markcell/host/defects_file.hpp"
#include "test_files.hpp"

using namespace markcell;
using namespace markcell::host;

namespace {
// The inspection station's scanner: 1392x1040, f = 2000 px (vision/RECORDING.md).
ScannerVolume scanner() {
  ScannerVolume v;
  v.fx = v.fy = 2000;
  v.cx = 696;
  v.cy = 520;
  v.width = 1392;
  v.height = 1040;
  v.z_min_m = 0.5;
  v.z_max_m = 4.0;
  return v;
}

const char* kCsv =
    "# defects of panel door-0001, CamL_SL, metres\n"
    "defect_id,x_m,y_m,z_m\n"
    "2,-0.031,0.234,1.990\n"
    "1,0.278,0.144,2.012\n"
    "1,0.268,0.149,2.012\r\n"
    "2,-0.038,0.234,1.989\n"
    "1,0.268,0.140,2.011\n"
    "2,-0.026,0.236,1.989\n";

const char* kPly =
    "ply\n"
    "format ascii 1.0\n"
    "comment the same points as kCsv, with a colour the reader ignores\n"
    "element vertex 6\n"
    "property float x\n"
    "property float y\n"
    "property float z\n"
    "property uchar red\n"
    "property int defect_id\n"
    "end_header\n"
    "-0.031 0.234 1.990 255 2\n"
    "0.278 0.144 2.012 255 1\n"
    "0.268 0.149 2.012 255 1\n"
    "-0.038 0.234 1.989 255 2\n"
    "0.268 0.140 2.011 255 1\n"
    "-0.026 0.236 1.989 255 2\n";

std::string refusal(const std::string& text, int min_points = 3) {
  try {
    parse_defects(text, "d.csv", scanner(), min_points);
  } catch (const DefectsInvalid& e) {
    return e.what();
  }
  return "(accepted)";
}
}  // namespace

TEST_CASE("the defects file: CSV and PLY of the same points give the same clusters, in ascending id") {
  const auto csv = parse_defects(kCsv, "d.csv", scanner());
  const auto ply = parse_defects(kPly, "d.ply", scanner());
  REQUIRE(csv.size() == 2);
  REQUIRE(ply.size() == 2);
  CHECK(csv[0].id == 1);
  CHECK(csv[1].id == 2);
  REQUIRE(csv[0].points_SL.size() == 3);
  CHECK(csv[0].points_SL[1] == Eigen::Vector3d(0.268, 0.149, 2.012));  // (the \r\n line)
  CHECK(csv[1].points_SL[0] == Eigen::Vector3d(-0.031, 0.234, 1.990));
  for (std::size_t k = 0; k < 2; ++k) {
    CHECK(ply[k].id == csv[k].id);
    CHECK(ply[k].points_SL == csv[k].points_SL);
  }
}

TEST_CASE("the defects file refused: NaN, behind the scanner, outside its image, too few points, bad headers") {
  const std::string head = "defect_id,x_m,y_m,z_m\n";
  CHECK(refusal(head + "1,nan,0.1,2.0\n1,0.1,0.1,2\n1,0.1,0.1,2\n") == "d.csv:2: x_m: 'nan' is not finite");
  CHECK(refusal(head + "1,0.1,0.1,-2.0\n") ==
        "d.csv:2: the point (0.100000, 0.100000, -2.000000) m is not between 0.500000 and 4.000000 m in front of the "
        "scanner (z)");
  // x / z * f + cx = 0.8 / 2 * 2000 + 696 = 1496 px, past the image's 1392.
  CHECK(refusal(head + "1,0.8,0.1,2.0\n") ==
        "d.csv:2: the point (0.800000, 0.100000, 2.000000) m is outside the scanner's left image (it projects to "
        "1496.000000, 620.000000 px of 1392x1040)");
  CHECK(refusal(head + "1,0.1,0.1,2\n1,0.1,0.1,2\n") == "d.csv: defect 1: 2 point(s), at least 3 needed");
  CHECK(refusal(head + "0,0.1,0.1,2\n") == "d.csv:2: defect_id: '0' is not an integer from 1 to 1000000");
  CHECK(refusal(head + "1,0.1,2\n") == "d.csv:2: 3 fields, expected 4 (defect_id,x_m,y_m,z_m)");
  CHECK(refusal("id,x,y,z\n") == "d.csv:1: expected the header 'defect_id,x_m,y_m,z_m', found 'id,x,y,z'");
  CHECK(refusal("") == "d.csv:0: no header 'defect_id,x_m,y_m,z_m': the file is empty");
  CHECK(refusal("ply\nformat binary_little_endian 1.0\n") == "d.csv:2: format 'binary_little_endian 1.0': only 'ascii 1.0' is read");
  CHECK(refusal("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n") ==
        "d.csv:5: the vertices need the properties x, y, z and defect_id");
  CHECK(refusal("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
                "property int defect_id\nend_header\n0.1 0.1 2 1\n") == "d.csv:9: vertex 1 of 2 missing");
  std::string many = head;
  for (int d = 1; d <= control::kMaxDefects + 1; ++d) many += std::to_string(d) + ",0.1,0.1,2\n";
  CHECK(refusal(many, 1) == "d.csv:" + std::to_string(control::kMaxDefects + 2) + ": defect " +
                                std::to_string(control::kMaxDefects + 1) + ": more than " +
                                std::to_string(control::kMaxDefects) + " defects in one file");
}

TEST_CASE("the defects file is read only as a regular file of bounded size") {
  test::TempDir dir;
  const std::string path = dir.write("d.csv", kCsv);
  CHECK(read_defects_file(path, scanner()).size() == 2);
  CHECK_THROWS_WITH(read_defects_file(dir.path().string(), scanner()),
                    Catch::Matchers::StartsWith(dir.path().string() + ": "));
  CHECK_THROWS_AS(read_defects_file((dir.path() / "missing.csv").string(), scanner()), DefectsInvalid);
}

TEST_CASE("the CSV writer: what it writes reads back as the same clusters") {
  const auto clusters = parse_defects(kCsv, "d.csv", scanner());
  const auto again = parse_defects(format_defects_csv(clusters), "again.csv", scanner());
  REQUIRE(again.size() == clusters.size());
  for (std::size_t d = 0; d < clusters.size(); ++d) {
    CHECK(again[d].id == clusters[d].id);
    REQUIRE(again[d].points_SL.size() == clusters[d].points_SL.size());
    for (std::size_t i = 0; i < clusters[d].points_SL.size(); ++i)
      CHECK((again[d].points_SL[i] - clusters[d].points_SL[i]).norm() < 1e-9);
  }
  CHECK(format_defects_csv({}) == "defect_id,x_m,y_m,z_m\n");
}
