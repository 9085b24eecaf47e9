// Tests of the map export (engine/io/map_image.hpp): files are read back by independent parsers
// (a PGM/YAML reader written here, libpng's own decoder).

#include "engine/io/map_image.hpp"

#include <gtest/gtest.h>
#include <png.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>

#include "engine/cell_encoding.hpp"
#include "engine/grid_geometry.hpp"
#include "engine/occupancy_grid.hpp"
#include "tests/map_file_support.hpp"

namespace slam::io {
namespace {

namespace fs = std::filesystem;
using testing::CountColor;
using testing::ParsePgm;
using testing::ParseYaml;
using testing::Pgm;
using testing::Pixel;
using testing::ReadFile;
using testing::ReadPng;

/// A fresh empty directory for one test's files.
std::string TestDir(const std::string& name) {
  const fs::path dir = fs::path(::testing::TempDir()) / ("map_image_test_" + name);
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

/// A 5 cm grid with known cells on both sides of the origin.
OccupancyGrid SampleGrid() {
  OccupancyGrid grid(GridGeometry(0.05), kLogOddsLimit);
  grid.BeginWrite();
  grid.Add({0, 0}, EncodeLogOdds(3.0));     // p = 0.95: occupied
  grid.Add({1, 0}, EncodeLogOdds(-3.0));    // p = 0.05: free
  grid.Add({2, 0}, EncodeLogOdds(0.2));     // p = 0.55: unknown
  grid.Add({3, 0}, EncodeLogOdds(-1.3));    // p = 0.214: above the free threshold, unknown
  grid.Add({4, 0}, EncodeLogOdds(-1.5));    // p = 0.182: free
  grid.Add({5, 0}, EncodeLogOdds(0.7));     // p = 0.668: occupied
  grid.Add({-1, -1}, EncodeLogOdds(2.0));   // in tile (-1, -1)
  grid.Add({-64, 63}, EncodeLogOdds(2.0));  // top-left corner of the picture
  return grid;
}

/// Pixel (col, row) of the top-down grid image holding cell (x, y) of SampleGrid().
uint8_t GrayAt(const GridImage& image, int x, int y) {
  const int col = x + 64;
  const int row = image.height - 1 - (y + 64);
  return image.gray[static_cast<size_t>(row * image.width + col)];
}

TEST(GridImageTest, MapServerTrinaryValuesWithTopRowAtLargestY) {
  const GridImage image = MakeGridImage(SampleGrid());
  // Tiles (-1, -1) .. (0, 0): 128 x 128 cells from (-3.2 m, -3.2 m).
  EXPECT_EQ(image.width, 128);
  EXPECT_EQ(image.height, 128);
  EXPECT_DOUBLE_EQ(image.resolution_m, 0.05);
  EXPECT_DOUBLE_EQ(image.origin_m.x(), -3.2);
  EXPECT_DOUBLE_EQ(image.origin_m.y(), -3.2);
  ASSERT_EQ(image.gray.size(), 128u * 128u);
  EXPECT_EQ(GrayAt(image, 0, 0), 0);
  EXPECT_EQ(GrayAt(image, 1, 0), 254);
  EXPECT_EQ(GrayAt(image, 2, 0), 205);
  EXPECT_EQ(GrayAt(image, 3, 0), 205);
  EXPECT_EQ(GrayAt(image, 4, 0), 254);
  EXPECT_EQ(GrayAt(image, 5, 0), 0);
  EXPECT_EQ(GrayAt(image, -1, -1), 0);
  EXPECT_EQ(GrayAt(image, 0, 1), 205);   // written tile, untouched cell
  EXPECT_EQ(GrayAt(image, -5, 5), 205);  // tile (-1, 0), untouched cell
  EXPECT_EQ(image.gray[0], 0);           // cell (-64, 63): top-left pixel
  int occupied = 0;
  for (const uint8_t g : image.gray) occupied += g == 0;
  EXPECT_EQ(occupied, 4);
}

TEST(GridImageTest, EmptyGridIsOneUnknownPixel) {
  const GridImage image = MakeGridImage(OccupancyGrid(GridGeometry(0.01), 5000));
  EXPECT_EQ(image.width, 1);
  EXPECT_EQ(image.height, 1);
  EXPECT_EQ(image.gray, std::vector<uint8_t>{205});
}

/// A parsed binary PGM: header fields and pixels, comments skipped.
TEST(MapFilesTest, PgmReadsBackWithTheSameValues) {
  const std::string dir = TestDir("pgm");
  const GridImage image = MakeGridImage(SampleGrid());
  ASSERT_TRUE(WritePgm(dir + "/map.pgm", image).ok());
  const Pgm pgm = ParsePgm(ReadFile(dir + "/map.pgm"));
  EXPECT_EQ(pgm.magic, "P5");
  EXPECT_EQ(pgm.width, 128);
  EXPECT_EQ(pgm.height, 128);
  EXPECT_EQ(pgm.maxval, 255);
  ASSERT_EQ(pgm.pixels.size(), 128u * 128u);
  EXPECT_EQ(std::vector<uint8_t>(pgm.pixels.begin(), pgm.pixels.end()), image.gray);
  // Cell (0, 0) occupied, (1, 0) free, (2, 0) unknown: row 63, columns 64..66.
  EXPECT_EQ(static_cast<uint8_t>(pgm.pixels[63 * 128 + 64]), 0);
  EXPECT_EQ(static_cast<uint8_t>(pgm.pixels[63 * 128 + 65]), 254);
  EXPECT_EQ(static_cast<uint8_t>(pgm.pixels[63 * 128 + 66]), 205);
  // Nothing but the map is left in the directory (no temporary files).
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 1);
}

TEST(MapFilesTest, YamlFollowsMapServer) {
  const std::string dir = TestDir("yaml");
  const GridImage image = MakeGridImage(SampleGrid());
  ASSERT_TRUE(WriteMapYaml(dir + "/map.yaml", "map.pgm", image).ok());
  const auto yaml = ParseYaml(ReadFile(dir + "/map.yaml"));
  EXPECT_EQ(yaml.size(), 6u);
  EXPECT_EQ(yaml.at("image"), "map.pgm");
  EXPECT_DOUBLE_EQ(std::stod(yaml.at("resolution")), 0.05);
  EXPECT_EQ(yaml.at("negate"), "0");
  EXPECT_DOUBLE_EQ(std::stod(yaml.at("occupied_thresh")), 0.65);
  EXPECT_DOUBLE_EQ(std::stod(yaml.at("free_thresh")), 0.196);
  // origin: [x, y, 0.0]
  std::string origin = yaml.at("origin");
  ASSERT_EQ(origin.front(), '[');
  ASSERT_EQ(origin.back(), ']');
  origin = origin.substr(1, origin.size() - 2);
  std::vector<double> xyz;
  std::istringstream parts(origin);
  std::string part;
  while (std::getline(parts, part, ',')) xyz.push_back(std::stod(part));
  ASSERT_EQ(xyz.size(), 3u);
  EXPECT_DOUBLE_EQ(xyz[0], -3.2);
  EXPECT_DOUBLE_EQ(xyz[1], -3.2);
  EXPECT_DOUBLE_EQ(xyz[2], 0.0);
}

TEST(MapFilesTest, WriteErrorsNameThePathAndLeaveNothingBehind) {
  const GridImage image = MakeGridImage(SampleGrid());
  const Result<void> written = WritePgm("/nonexistent-dir/map.pgm", image);
  ASSERT_FALSE(written.ok());
  EXPECT_NE(written.Message().find("/nonexistent-dir/map.pgm"), std::string::npos)
      << written.Message();
  EXPECT_FALSE(WriteMapYaml("/nonexistent-dir/map.yaml", "map.pgm", image).ok());
  EXPECT_FALSE(WritePng("/nonexistent-dir/map.png", RenderMapPicture(SampleGrid(), {}, 1)).ok());
  // A directory in the way of the final name: the rename fails, the temporary file is removed.
  const std::string dir = TestDir("blocked");
  fs::create_directory(dir + "/map.pgm");
  EXPECT_FALSE(WritePgm(dir + "/map.pgm", image).ok());
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 1);
  // Inconsistent images are refused.
  GridImage broken = image;
  broken.gray.pop_back();
  EXPECT_FALSE(WritePgm(dir + "/other.pgm", broken).ok());
}

TEST(MapFilesTest, WriteReplacesAnExistingFile) {
  const std::string dir = TestDir("replace");
  {
    std::ofstream old(dir + "/map.yaml");
    old << "stale contents that are longer than the new file will be, by quite a lot ......\n"
        << std::string(1000, 'x');
  }
  ASSERT_TRUE(WriteMapYaml(dir + "/map.yaml", "map.pgm", MakeGridImage(SampleGrid())).ok());
  EXPECT_EQ(ReadFile(dir + "/map.yaml").find("stale"), std::string::npos);
  EXPECT_EQ(ParseYaml(ReadFile(dir + "/map.yaml")).at("image"), "map.pgm");
}

TEST(PngTest, EncodedBytesAreAValidPng) {
  RgbImage image;
  image.width = 3;
  image.height = 2;
  image.rgb = {255, 0, 0, 0, 255, 0, 0, 0, 255, 10, 20, 30, 40, 50, 60, 70, 80, 90};
  const Result<PngBytes> png = EncodePng(image);
  ASSERT_TRUE(png.ok()) << png.Message();
  ASSERT_GT(png.value().size(), 8u);
  EXPECT_EQ(png_sig_cmp(png.value().data(), 0, 8), 0);
  const std::string dir = TestDir("png");
  ASSERT_TRUE(WritePng(dir + "/small.png", image).ok());
  const RgbImage back = ReadPng(dir + "/small.png");
  EXPECT_EQ(back.width, 3);
  EXPECT_EQ(back.height, 2);
  EXPECT_EQ(back.rgb, image.rgb);
}

TEST(PngTest, GrayPngAndInvalidImages) {
  const Result<PngBytes> gray = EncodeGrayPng(2, 2, {0, 100, 200, 255});
  ASSERT_TRUE(gray.ok());
  png_image png{};
  png.version = PNG_IMAGE_VERSION;
  ASSERT_TRUE(png_image_begin_read_from_memory(&png, gray.value().data(), gray.value().size()));
  EXPECT_EQ(png.format, static_cast<png_uint_32>(PNG_FORMAT_GRAY));
  std::vector<uint8_t> pixels(PNG_IMAGE_SIZE(png));
  ASSERT_TRUE(png_image_finish_read(&png, nullptr, pixels.data(), 0, nullptr));
  EXPECT_EQ(pixels, (std::vector<uint8_t>{0, 100, 200, 255}));

  EXPECT_FALSE(EncodeGrayPng(2, 2, {0, 1, 2}).ok());
  EXPECT_FALSE(EncodePng(RgbImage{}).ok());
  EXPECT_FALSE(EncodeGrayPng(0, 5, {}).ok());
}

TEST(MapPictureTest, MapTrajectoriesAndLegend) {
  // 1 cm grid, a wall of occupied cells along y = 0.30 m, free cells below it.
  OccupancyGrid grid(GridGeometry(0.01), 5000);
  grid.BeginWrite();
  for (int x = 5; x < 55; ++x) {
    grid.Add({x, 30}, EncodeLogOdds(4.0));
    for (int y = 5; y < 30; ++y) grid.Add({x, y}, EncodeLogOdds(-4.0));
  }
  const std::array<uint8_t, 3> red{255, 0, 0}, blue{0, 0, 255};
  TrajectoryLayer slam{"SLAM", {{0.0, {0.1025, 0.1025, 0.0}}, {1.0, {0.4525, 0.1025, 0.0}}}, red};
  TrajectoryLayer truth{
      "ground truth (aligned)", {{0.0, {0.1025, 0.2025, 0.0}}, {1.0, {0.4525, 0.2025, 0.0}}}, blue};
  const std::string dir = TestDir("picture");
  const RgbImage picture = RenderMapPicture(grid, {slam, truth}, 2);
  ASSERT_TRUE(WritePng(dir + "/map.png", picture).ok());
  const RgbImage image = ReadPng(dir + "/map.png");

  // One tile (64 cells) at 2 pixels per cell, then a legend of two lines (11 px each + 4).
  ASSERT_EQ(image.width, picture.width);
  EXPECT_EQ(image.height, 128 + 2 * 11 + 4);
  EXPECT_GE(image.width, 128);
  EXPECT_EQ(image.rgb, picture.rgb);

  // Map: the wall (cell row 30 -> pixel rows 66, 67) is dark grey, below it light grey.
  const auto wall = Pixel(image, 20 * 2, 67);
  EXPECT_LT(wall[0], 10);
  EXPECT_EQ(wall[0], wall[2]);
  const auto free = Pixel(image, 20 * 2, 97);
  EXPECT_GT(free[0], 245);
  EXPECT_EQ(free[0], free[2]);
  // Unknown cells are neither black nor white nor grey.
  const auto unknown = Pixel(image, 120, 2);
  EXPECT_NE(unknown[0], unknown[2]);

  // SLAM in red along y = 0.1025 m (pixel row 128 - 20.5 -> 107) from x = 20 to 90 px.
  EXPECT_EQ(Pixel(image, 50, 107), red);
  EXPECT_EQ(CountColor(image, 20, 107, 91, 108, red), 71);
  EXPECT_EQ(CountColor(image, 0, 0, image.width, 128, red), 71);
  // Ground truth in blue along y = 0.2025 m (pixel row 87).
  EXPECT_EQ(CountColor(image, 20, 87, 91, 88, blue), 71);
  EXPECT_EQ(CountColor(image, 0, 0, image.width, 128, blue), 71);

  // Legend: a swatch in each colour and black text right of it.
  EXPECT_GT(CountColor(image, 0, 128, image.width, 128 + 13, red), 10);
  EXPECT_GT(CountColor(image, 0, 128 + 13, image.width, image.height, blue), 10);
  const int text = CountColor(image, 20, 128, image.width, image.height, {0, 0, 0});
  EXPECT_GT(text, 100);
  EXPECT_EQ(CountColor(image, 0, 128, image.width, image.height, {0, 0, 0}), text);
}

TEST(MapPictureTest, GrowsOverTrajectoriesOutsideTheMap) {
  OccupancyGrid grid(GridGeometry(0.01), 5000);
  TrajectoryLayer far{
      "odometry only", {{0.0, {-1.0, -0.5, 0.0}}, {1.0, {1.0, 0.5, 0.0}}}, {128, 128, 128}};
  const RgbImage image = RenderMapPicture(grid, {far}, 1);
  // 200 x 100 cm of trajectory plus a margin of two cells each side.
  EXPECT_EQ(image.width, 205);
  EXPECT_EQ(image.height, 105 + 11 + 4);
  EXPECT_EQ(Pixel(image, 2, 103), (std::array<uint8_t, 3>{128, 128, 128}));  // start
  EXPECT_EQ(Pixel(image, 202, 3), (std::array<uint8_t, 3>{128, 128, 128}));  // end
}

}  // namespace
}  // namespace slam::io

namespace slam::io {
namespace {

TEST(TileGray, UnknownOccupiedFreeAndRowOrder) {
  Tile tile;
  tile.cells[0] = EncodeLogOdds(20.0);                // cell (0, 0): bottom-left, occupied
  tile.cells[kTileCells - 1] = EncodeLogOdds(-20.0);  // cell (63, 63): top-right, free
  tile.cells[static_cast<size_t>(kTileSize + 1)] = EncodeLogOdds(0.001);  // (1, 1): barely
  const std::vector<uint8_t> gray = TileGray(tile);
  ASSERT_EQ(gray.size(), static_cast<size_t>(kTileCells));
  const auto at = [&](int x, int y) {
    return gray[static_cast<size_t>((kTileSize - 1 - y) * kTileSize + x)];
  };
  EXPECT_EQ(at(0, 0), 0);      // row 63 of the image: the bottom
  EXPECT_EQ(at(63, 63), 254);  // row 0: the top
  EXPECT_EQ(at(1, 1), 127);    // p just above 0.5
  EXPECT_EQ(at(5, 7), kUnknownGray);
  EXPECT_EQ(gray.front(), kUnknownGray);  // top-left pixel is cell (0, 63): never written
}

}  // namespace
}  // namespace slam::io
