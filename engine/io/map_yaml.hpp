#pragma once
// Reading a ROS map_server map (map.yaml and its image) into an occupancy grid: a map that
// slam-replay or slamd exported (map_image.hpp), or another tool's, to localise on.
//
// map.yaml is read as map_server writes it: one `key: value` per line at the top level,
// comments after '#', `origin` a flow sequence `[x, y, yaw]`. Required keys: image, resolution,
// origin, negate, occupied_thresh, free_thresh; optional: mode (trinary, scale or raw). Other
// keys are ignored, as map_server ignores them; nested or multi-line values are refused. The
// image is a binary PGM (P5, at most 8 bits) or a PNG (any colour type, through libpng), told
// apart by its first bytes; its path is relative to the yaml's folder unless absolute.
//
// A pixel's occupancy is map_server's (ROS 1 image_loader): c, the mean of its colour channels
// (0..255; in trinary mode an alpha channel is averaged in, as map_server does), negated when
// `negate` (255 - c), then p = (255 - c) / 255. Trinary: occupied when p > occupied_thresh,
// free when p < free_thresh, else unknown. Scale: a pixel whose alpha is below 255 is unknown,
// else as trinary, and one between the thresholds holds the log odds of p. Raw: c is the
// occupancy in percent (0 free, 100 occupied, between: the log odds of c / 100, above 100
// unknown).

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "engine/grid_geometry.hpp"
#include "engine/occupancy_grid.hpp"
#include "engine/pose.hpp"
#include "engine/result.hpp"

namespace slam::io {

/// map_server's `mode`: how a pixel's value becomes occupancy.
enum class MapMode { kTrinary, kScale, kRaw };

/// The keys of a map.yaml.
struct MapYamlKeys {
  std::string image;          // as written: relative to the yaml's folder unless absolute
  double resolution_m = 0.0;  // of a pixel
  /// The world pose of the image's lower-left corner (the bottom-left pixel's outer corner):
  /// the image is rotated by origin.theta about it.
  Pose2 origin;
  bool negate = false;
  double occupied_thresh = 0.65;
  double free_thresh = 0.196;
  MapMode mode = MapMode::kTrinary;
};

/// Parses map.yaml text; each error names `path`, the line and the key (a missing key, a wrong
/// type, a number that is not finite, thresholds outside [0, 1] or not free < occupied).
Result<MapYamlKeys> ParseMapYaml(std::string_view text, const std::string& path);

/// Images bigger than the map's bound holds cells a side are refused: no pixel finer than a
/// cell of the map is of use, and a header must not make the reader allocate gigabytes.
inline constexpr int kMaxMapImageSide = 2 * kMapCellBound;

/// An image as map_server reads it: per pixel (row 0 at the top) the sum of its colour
/// channels (their mean is the pixel's value), and its alpha.
struct MapPixels {
  int width = 0;
  int height = 0;
  int colour_channels = 1;     // 1 (grey) or 3 (RGB)
  std::vector<uint16_t> sum;   // width * height: the colour channels' sum, each 0..255
  std::vector<uint8_t> alpha;  // width * height; empty for an image without alpha (opaque)

  /// The mean of pixel i's colour channels, 0..255.
  double Value(size_t i) const { return sum[i] / static_cast<double>(colour_channels); }
};

/// Decodes a binary PGM (P5, maxval up to 255, scaled to 255) or a PNG; errors name `path`
/// (not an image of either kind, a header that does not parse, truncated pixels, a side of 0 or
/// beyond kMaxMapImageSide).
Result<MapPixels> DecodeMapImage(std::string_view bytes, const std::string& path);

/// Reads `yaml_path` and its image into a grid of `geometry`, cells clamped to [-limit, limit]
/// (encoded log odds, 0 < limit <= kLogOddsLimit): occupied pixels at +limit, free ones at
/// -limit, unknown ones 0 (not written). Each cell takes the pixel under its centre (nearest
/// cell, whatever the two resolutions and the origin's yaw). Errors name the file and, for the
/// yaml, the line: unreadable files, the yaml's errors, the image's, an image reaching beyond
/// the map's bound at `geometry`'s resolution.
Result<OccupancyGrid> LoadMapYaml(const std::string& yaml_path, const GridGeometry& geometry,
                                  int limit);

}  // namespace slam::io
