#pragma once
// Map export: the ROS map_server pair (PGM + YAML), PNG encoding through libpng, and a picture
// of the map with trajectories and a legend for people to look at.

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "engine/occupancy_grid.hpp"
#include "engine/pose.hpp"
#include "engine/result.hpp"

namespace slam::io {

/// ROS map_server thresholds: a cell is occupied at p >= 0.65, free at p <= 0.196.
inline constexpr double kOccupiedThreshold = 0.65;
inline constexpr double kFreeThreshold = 0.196;
inline constexpr uint8_t kOccupiedGray = 0;
inline constexpr uint8_t kFreeGray = 254;
inline constexpr uint8_t kUnknownGray = 205;

/// An 8-bit grey image of a grid, one pixel per cell (or per square of cells_per_pixel cells a
/// side), row 0 at the top (largest y).
struct GridImage {
  int width = 0;
  int height = 0;
  double resolution_m = 0.0;  // of a pixel: the grid's resolution times cells_per_pixel
  Vec2 origin_m =
      Vec2::Zero();           // world position of the bottom-left corner of the bottom-left pixel
  std::vector<uint8_t> gray;  // width * height, row-major from the top row
  int cells_per_pixel = 1;
};

/// Whole-map images hold at most this many pixels (16 Mi: 16 MiB of grey, a 41 m square at
/// 1 cm cells, the whole map's bound at 4 cm): a map spread wider is exported coarser, so that
/// two tiles far apart cost megabytes, not the 268 Mpx of the bound's box at full resolution.
inline constexpr int64_t kMaxGridImagePixels = int64_t{1} << 24;

/// The grid over the bounds of its tiles in map_server's trinary convention (0 occupied, 254
/// free, 205 unknown); an empty grid gives one unknown pixel at the origin. When that box has
/// more than `max_pixels` cells, each pixel is the smallest square of n x n cells that fits
/// (occupied if any cell is, else free if any is, else unknown), and resolution_m says so.
GridImage MakeGridImage(const OccupancyGrid& grid, int64_t max_pixels = kMaxGridImagePixels);

/// A 24-bit RGB image, row 0 at the top.
struct RgbImage {
  int width = 0;
  int height = 0;
  std::vector<uint8_t> rgb;  // width * height * 3, row-major from the top row
};

/// The cells of one tile as 8-bit grey pixels (kTileSize squared, row 0 at the top, i.e. the
/// largest y), as slamd serves tiles: 205 where unknown (log odds exactly 0), else
/// 254 * (1 - p), so that 0 is surely occupied and 254 surely free.
std::vector<uint8_t> TileGray(const Tile& tile);

/// The binary PGM (P5) file contents of a grid image.
std::string EncodePgm(const GridImage& image);

/// The map_server YAML describing `image` stored in the file `pgm_name` (relative to the YAML).
std::string MapYaml(const std::string& pgm_name, const GridImage& image);

/// PNG file contents.
using PngBytes = std::vector<uint8_t>;

/// Encodes an RGB image as an 8-bit RGB PNG.
Result<PngBytes> EncodePng(const RgbImage& image);

/// Encodes an 8-bit grey image (width * height bytes, row 0 at the top) as a grey PNG.
Result<PngBytes> EncodeGrayPng(int width, int height, const std::vector<uint8_t>& gray);

/// Writes a grid image as a binary PGM file, atomically.
Result<void> WritePgm(const std::string& path, const GridImage& image);

/// Writes the map_server YAML for `image` stored as `pgm_name`, atomically.
Result<void> WriteMapYaml(const std::string& path, const std::string& pgm_name,
                          const GridImage& image);

/// Writes an RGB image as a PNG file, atomically.
Result<void> WritePng(const std::string& path, const RgbImage& image);

/// A trajectory to draw on the map picture.
struct TrajectoryLayer {
  std::string name;  // legend text (letters, digits, space and - . , : ( ) / _ + %)
  std::vector<TimedPose> poses;
  std::array<uint8_t, 3> color{255, 0, 0};
  /// Whether the picture grows to hold every point of this layer. False for one that may
  /// wander far off the map (dead reckoning): it is drawn where it crosses the picture, and
  /// the map keeps its size.
  bool fit = true;
};

/// A scale bar's round length (1, 2 or 5 times a power of ten metres), its pixels and label.
struct ScaleBar {
  double length_m = 0.0;
  int length_px = 0;
  std::string label;  // "50 cm", "2 m"
};

/// The longest round length that spans at most `max_px` pixels (at least 1) at
/// `metres_per_pixel` (> 0).
ScaleBar ChooseScaleBar(double metres_per_pixel, int max_px);

/// The map (grey levels from the occupancy probability, unknown in a light blue-grey) at
/// `scale` pixels per cell (>= 1), the trajectories as lines in their colours, and a strip
/// below the map with a legend naming each trajectory and a scale bar (at the right of the
/// legend's first line). The picture covers the grid's tiles and every point of the layers that
/// fit (all of them when the grid is empty).
RgbImage RenderMapPicture(const OccupancyGrid& grid, const std::vector<TrajectoryLayer>& layers,
                          int scale);

}  // namespace slam::io
