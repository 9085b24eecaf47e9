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

/// An 8-bit grey image of a grid, one pixel per cell, row 0 at the top (largest y).
struct GridImage {
  int width = 0;
  int height = 0;
  double resolution_m = 0.0;
  Vec2 origin_m =
      Vec2::Zero();           // world position of the bottom-left corner of the bottom-left pixel
  std::vector<uint8_t> gray;  // width * height, row-major from the top row
};

/// The grid over the bounds of its tiles in map_server's trinary convention (0 occupied, 254
/// free, 205 unknown); an empty grid gives one unknown pixel at the origin.
GridImage MakeGridImage(const OccupancyGrid& grid);

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
};

/// The map (grey levels from the occupancy probability, unknown in a light blue-grey) at
/// `scale` pixels per cell (>= 1), the trajectories as lines in their colours, and a legend
/// strip below the map naming each trajectory. The picture covers the grid's tiles and every
/// trajectory point.
RgbImage RenderMapPicture(const OccupancyGrid& grid, const std::vector<TrajectoryLayer>& layers,
                          int scale);

}  // namespace slam::io
