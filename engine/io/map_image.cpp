#include "engine/io/map_image.hpp"

#include <png.h>

#include <algorithm>
#include <charconv>
#include <climits>
#include <cmath>
#include <csetjmp>
#include <cstdio>
#include <type_traits>

#include "engine/cell_encoding.hpp"
#include "engine/grid_geometry.hpp"
#include "engine/io/atomic_file.hpp"
#include "engine/io/canvas.hpp"

namespace slam::io {
namespace {

/// Shortest text that reads back as the same double.
std::string FormatNumber(double v) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), v);
  std::string text(buffer, result.ptr);
  if (text.find_first_of(".eEn") == std::string::npos) text += ".0";  // YAML float, not int
  return text;
}

/// Cell window [x0, x0 + width) x [y0, y0 + height) in cells.
struct CellWindow {
  int64_t x0 = 0;
  int64_t y0 = 0;
  int64_t width = 0;
  int64_t height = 0;
};

/// The cells covered by the grid's tiles (empty window for an empty grid).
CellWindow TileWindow(const std::vector<TileRef>& tiles) {
  if (tiles.empty()) return {};
  int64_t tx0 = INT64_MAX, ty0 = INT64_MAX, tx1 = INT64_MIN, ty1 = INT64_MIN;
  for (const TileRef& t : tiles) {
    tx0 = std::min<int64_t>(tx0, t.index.x);
    ty0 = std::min<int64_t>(ty0, t.index.y);
    tx1 = std::max<int64_t>(tx1, t.index.x);
    ty1 = std::max<int64_t>(ty1, t.index.y);
  }
  return {tx0 * kTileSize, ty0 * kTileSize, (tx1 - tx0 + 1) * kTileSize,
          (ty1 - ty0 + 1) * kTileSize};
}

/// Calls f(column, row, log_odds) for every cell of the window held by a tile (row 0 = top).
template <typename F>
void ForEachTileCell(const std::vector<TileRef>& tiles, const CellWindow& window, F&& f) {
  for (const TileRef& t : tiles) {
    const CellIndex origin = GridGeometry::TileOrigin(t.index);
    for (int j = 0; j < kTileSize; ++j) {
      const int64_t row = window.height - 1 - (origin.y + j - window.y0);
      if (row < 0 || row >= window.height) continue;
      for (int i = 0; i < kTileSize; ++i) {
        const int64_t col = origin.x + i - window.x0;
        if (col < 0 || col >= window.width) continue;
        f(col, row, t.tile->cells[static_cast<size_t>(j * kTileSize + i)]);
      }
    }
  }
}

// ---------------------------------------------------------------------------------------------
// PNG through libpng, into memory. libpng reports errors by longjmp: the frame holding setjmp
// (WriteRows) has only trivially destructible locals, and the output vector lives in the caller.

void AppendToVector(png_structp png, png_bytep data, png_size_t length) {
  auto* out = static_cast<std::vector<uint8_t>*>(png_get_io_ptr(png));
  out->insert(out->end(), data, data + length);
}

void FlushNothing(png_structp) {}

void StoreError(png_structp png, png_const_charp message) {
  auto* error = static_cast<char*>(png_get_error_ptr(png));
  std::snprintf(error, 256, "%s", message);
  png_longjmp(png, 1);
}

void IgnoreWarning(png_structp, png_const_charp) {}

/// Encodes rows of `channels` bytes per pixel; returns false (with `error` set) on failure.
bool WriteRows(png_structp png, png_infop info, int width, int height, int color_type, int channels,
               const uint8_t* pixels, std::vector<uint8_t>* out) {
  if (setjmp(png_jmpbuf(png))) return false;
  png_set_write_fn(png, out, AppendToVector, FlushNothing);
  png_set_IHDR(png, info, static_cast<png_uint_32>(width), static_cast<png_uint_32>(height), 8,
               color_type, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
               PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  const size_t stride = static_cast<size_t>(width) * static_cast<size_t>(channels);
  for (int y = 0; y < height; ++y) {
    // libpng does not write through the row pointer; the cast only drops const.
    png_write_row(png, const_cast<png_bytep>(pixels + static_cast<size_t>(y) * stride));
  }
  png_write_end(png, nullptr);
  return true;
}

Result<PngBytes> Encode(int width, int height, int color_type, int channels, const uint8_t* pixels,
                        size_t size) {
  if (width <= 0 || height <= 0) return Error("cannot encode an empty image as PNG");
  if (size !=
      static_cast<size_t>(width) * static_cast<size_t>(height) * static_cast<size_t>(channels)) {
    return Error("image data does not match its size");
  }
  char error[256] = "libpng failed";
  png_structp png =
      png_create_write_struct(PNG_LIBPNG_VER_STRING, error, StoreError, IgnoreWarning);
  if (png == nullptr) return Error("cannot initialise libpng");
  png_infop info = png_create_info_struct(png);
  if (info == nullptr) {
    png_destroy_write_struct(&png, nullptr);
    return Error("cannot initialise libpng");
  }
  PngBytes bytes;
  const bool ok = WriteRows(png, info, width, height, color_type, channels, pixels, &bytes);
  png_destroy_write_struct(&png, &info);
  if (!ok) return Error(std::string("PNG encoding failed: ") + error);
  return bytes;
}

// ---------------------------------------------------------------------------------------------
// The map picture's colours.

constexpr Rgb kUnknownColor{205, 210, 220};
constexpr Rgb kLegendBackground{255, 255, 255};
constexpr Rgb kLegendText{0, 0, 0};

}  // namespace

GridImage MakeGridImage(const OccupancyGrid& grid, int64_t max_pixels) {
  const std::vector<TileRef> tiles = grid.Tiles();
  const CellWindow window = TileWindow(tiles);
  GridImage image;
  image.resolution_m = grid.geometry().resolution();
  if (window.width == 0) {
    image.width = image.height = 1;
    image.gray = {kUnknownGray};
    return image;
  }
  // The smallest whole number of cells per pixel side that keeps the picture within the cap.
  // The window is at most 2 * kMapTileBound tiles a side, so n stays small (at most the side).
  max_pixels = std::max<int64_t>(1, max_pixels);
  int64_t n = 1;
  const auto pixels = [&](int64_t k) {
    return ((window.width + k - 1) / k) * ((window.height + k - 1) / k);
  };
  while (pixels(n) > max_pixels) ++n;
  image.cells_per_pixel = static_cast<int>(n);
  image.resolution_m = grid.geometry().resolution() * static_cast<double>(n);
  image.width = static_cast<int>((window.width + n - 1) / n);
  image.height = static_cast<int>((window.height + n - 1) / n);
  // The pixel grid starts at the window's lower-left cell; the top row and right column may
  // reach past the window (cells no tile holds: unknown).
  image.origin_m = grid.geometry().CellCorner(
      {static_cast<int32_t>(window.x0), static_cast<int32_t>(window.y0)});
  image.gray.assign(static_cast<size_t>(image.width) * static_cast<size_t>(image.height),
                    kUnknownGray);
  // Each log odds' map_server value, once (the thresholds cost an exp per cell otherwise).
  static_assert(std::is_same_v<LogOdds, int16_t>, "the table covers 16-bit log odds");
  std::vector<uint8_t> value_of(size_t{1} << 16);
  for (int v = INT16_MIN; v <= INT16_MAX; ++v) {
    const double p = OccupancyProbability(static_cast<LogOdds>(v));
    value_of[static_cast<uint16_t>(v)] = p >= kOccupiedThreshold ? kOccupiedGray
                                         : p <= kFreeThreshold   ? kFreeGray
                                                                 : kUnknownGray;
  }
  // Cells merge into a pixel by precedence: occupied over free over unknown. Only tiles are
  // visited, so the time is the tiles', not the box's.
  for (const TileRef& t : tiles) {
    const CellIndex origin = GridGeometry::TileOrigin(t.index);
    for (int j = 0; j < kTileSize; ++j) {
      const int64_t row = image.height - 1 - (origin.y + j - window.y0) / n;
      uint8_t* line =
          image.gray.data() + static_cast<size_t>(row) * static_cast<size_t>(image.width);
      for (int i = 0; i < kTileSize; ++i) {
        const uint8_t value =
            value_of[static_cast<uint16_t>(t.tile->cells[static_cast<size_t>(j * kTileSize + i)])];
        uint8_t& pixel = line[(origin.x + i - window.x0) / n];
        if (value == kOccupiedGray || (value == kFreeGray && pixel == kUnknownGray)) {
          pixel = value;
        }
      }
    }
  }
  return image;
}

std::vector<uint8_t> TileGray(const Tile& tile) {
  std::vector<uint8_t> gray(kTileCells);
  for (int row = 0; row < kTileSize; ++row) {
    const int y = kTileSize - 1 - row;  // row 0 at the top: the largest y
    for (int x = 0; x < kTileSize; ++x) {
      const LogOdds cell = tile.cells[static_cast<size_t>(y * kTileSize + x)];
      uint8_t& pixel = gray[static_cast<size_t>(row * kTileSize + x)];
      pixel = cell == 0
                  ? kUnknownGray
                  : static_cast<uint8_t>(std::lround(254.0 * (1.0 - OccupancyProbability(cell))));
    }
  }
  return gray;
}

std::string EncodePgm(const GridImage& image) {
  std::string out = "P5\n# CREATOR: marxbot-slam " + FormatNumber(image.resolution_m) + " m/pix\n" +
                    std::to_string(image.width) + " " + std::to_string(image.height) + "\n255\n";
  out.append(image.gray.begin(), image.gray.end());
  return out;
}

std::string MapYaml(const std::string& pgm_name, const GridImage& image) {
  return "image: " + pgm_name + "\nresolution: " + FormatNumber(image.resolution_m) +
         "\norigin: [" + FormatNumber(image.origin_m.x()) + ", " +
         FormatNumber(image.origin_m.y()) +
         ", 0.0]\nnegate: 0\noccupied_thresh: " + FormatNumber(kOccupiedThreshold) +
         "\nfree_thresh: " + FormatNumber(kFreeThreshold) + "\n";
}

Result<PngBytes> EncodePng(const RgbImage& image) {
  return Encode(image.width, image.height, PNG_COLOR_TYPE_RGB, 3, image.rgb.data(),
                image.rgb.size());
}

Result<PngBytes> EncodeGrayPng(int width, int height, const std::vector<uint8_t>& gray) {
  return Encode(width, height, PNG_COLOR_TYPE_GRAY, 1, gray.data(), gray.size());
}

Result<void> WritePgm(const std::string& path, const GridImage& image) {
  if (image.width <= 0 || image.height <= 0 ||
      image.gray.size() != static_cast<size_t>(image.width) * static_cast<size_t>(image.height)) {
    return Error("cannot write " + path + ": image data does not match its size");
  }
  return WriteFileAtomic(path, EncodePgm(image));
}

Result<void> WriteMapYaml(const std::string& path, const std::string& pgm_name,
                          const GridImage& image) {
  return WriteFileAtomic(path, MapYaml(pgm_name, image));
}

Result<void> WritePng(const std::string& path, const RgbImage& image) {
  const Result<PngBytes> png = EncodePng(image);
  if (!png.ok()) return Error("cannot write " + path + ": " + png.Message());
  return WriteFileAtomic(path, std::string(png.value().begin(), png.value().end()));
}

ScaleBar ChooseScaleBar(double metres_per_pixel, int max_px) {
  max_px = std::max(1, max_px);
  if (!(metres_per_pixel > 0.0) || !std::isfinite(metres_per_pixel)) return {0.0, 0, ""};
  const double longest_m = metres_per_pixel * max_px;
  double decade = std::pow(10.0, std::floor(std::log10(longest_m)));
  double length_m = decade;
  for (const double step : {5.0, 2.0, 1.0}) {
    if (step * decade <= longest_m * (1.0 + 1e-9)) {
      length_m = step * decade;
      break;
    }
  }
  ScaleBar bar;
  bar.length_m = length_m;
  bar.length_px = std::clamp(static_cast<int>(std::lround(length_m / metres_per_pixel)), 1, max_px);
  char label[32];
  if (length_m >= 1.0) {
    std::snprintf(label, sizeof(label), "%g m", length_m);
  } else if (length_m >= 0.01) {
    std::snprintf(label, sizeof(label), "%g cm", length_m * 100.0);
  } else {
    std::snprintf(label, sizeof(label), "%g mm", length_m * 1000.0);
  }
  bar.label = label;
  return bar;
}

RgbImage RenderMapPicture(const OccupancyGrid& grid, const std::vector<TrajectoryLayer>& layers,
                          int scale) {
  scale = std::max(1, scale);
  const GridGeometry& geometry = grid.geometry();
  const std::vector<TileRef> tiles = grid.Tiles();
  CellWindow window = TileWindow(tiles);

  // Grow the window over every trajectory point, with a margin of two cells.
  int64_t x0 = window.width > 0 ? window.x0 : INT64_MAX;
  int64_t y0 = window.height > 0 ? window.y0 : INT64_MAX;
  int64_t x1 = window.width > 0 ? window.x0 + window.width : INT64_MIN;
  int64_t y1 = window.height > 0 ? window.y0 + window.height : INT64_MIN;
  // Layers that fit first; the others only when nothing else gives the picture a size.
  const auto grow_over = [&](bool fitting_only) {
    for (const TrajectoryLayer& layer : layers) {
      if (fitting_only && !layer.fit) continue;
      for (const TimedPose& p : layer.poses) {
        if (!std::isfinite(p.pose.x) || !std::isfinite(p.pose.y)) continue;
        const Vec2 g = geometry.ToGrid(p.pose.translation());
        const auto cx = static_cast<int64_t>(std::floor(std::clamp(g.x(), -1e9, 1e9)));
        const auto cy = static_cast<int64_t>(std::floor(std::clamp(g.y(), -1e9, 1e9)));
        x0 = std::min(x0, cx - 2);
        y0 = std::min(y0, cy - 2);
        x1 = std::max(x1, cx + 3);
        y1 = std::max(y1, cy + 3);
      }
    }
  };
  grow_over(true);
  if (x0 >= x1 || y0 >= y1) grow_over(false);
  if (x0 >= x1 || y0 >= y1) {
    x0 = y0 = 0;
    x1 = y1 = 1;
  }
  // Keep pictures of diverging trajectories within reason (8192 pixels a side).
  const int64_t max_cells = std::max<int64_t>(1, 8192 / scale);
  x1 = std::min(x1, x0 + max_cells);
  y1 = std::min(y1, y0 + max_cells);
  window = {x0, y0, x1 - x0, y1 - y0};

  // Legend layout: one line per layer, a colour swatch then the name.
  const int map_width = static_cast<int>(window.width) * scale;
  const int map_height = static_cast<int>(window.height) * scale;
  const int font = map_width >= 300 ? 2 : 1;
  const int line_height = (Canvas::kGlyphHeight + 4) * font;
  const int swatch = 6 * Canvas::kGlyphAdvance * font / 2;
  int legend_width = 0;
  for (const TrajectoryLayer& layer : layers) {
    const int text_width = Canvas::TextWidth(layer.name, font);
    legend_width = std::max(legend_width, swatch + text_width + 8 * font);
  }
  // The scale bar, right of the legend's first line: a round length near a fifth of the map's
  // width (at least 40 pixels), with its label after it.
  const ScaleBar bar = ChooseScaleBar(geometry.resolution() / scale, std::max(40, map_width / 5));
  const int bar_width = bar.length_px + 2 * font + Canvas::TextWidth(bar.label, font) + 3 * font;
  const int legend_height =
      static_cast<int>(std::max<size_t>(layers.size(), 1)) * line_height + 4 * font;
  const int width = std::max(map_width, legend_width + 4 * font + bar_width);
  Canvas canvas(width, map_height + legend_height, kLegendBackground);

  // The map: unknown where nothing was ever observed, else grey from the probability.
  canvas.FillRect(0, 0, map_width, map_height, kUnknownColor);
  ForEachTileCell(tiles, window, [&](int64_t col, int64_t row, LogOdds value) {
    if (value == 0) return;
    const auto level =
        static_cast<uint8_t>(std::lround(255.0 * (1.0 - OccupancyProbability(value))));
    canvas.FillRect(col * scale, row * scale, scale, scale, {level, level, level});
  });

  // Trajectories, in order (later layers on top).
  const int thickness = std::max(1, (scale + 1) / 2);
  const auto to_pixel = [&](const Pose2& p) {
    const Vec2 g = geometry.ToGrid(p.translation());
    const double px = (g.x() - static_cast<double>(window.x0)) * scale;
    const double py =
        static_cast<double>(map_height) - (g.y() - static_cast<double>(window.y0)) * scale;
    return std::pair<int64_t, int64_t>{static_cast<int64_t>(std::floor(std::clamp(px, -1e6, 1e6))),
                                       static_cast<int64_t>(std::floor(std::clamp(py, -1e6, 1e6)))};
  };
  for (const TrajectoryLayer& layer : layers) {
    for (size_t i = 0; i < layer.poses.size(); ++i) {
      const auto [ax, ay] = to_pixel(layer.poses[i == 0 ? 0 : i - 1].pose);
      const auto [bx, by] = to_pixel(layer.poses[i].pose);
      canvas.Line(ax, ay, bx, by, thickness, layer.color);
    }
  }

  // Legend strip below the map.
  for (size_t k = 0; k < layers.size(); ++k) {
    const int y = map_height + 2 * font + static_cast<int>(k) * line_height;
    canvas.FillRect(3 * font, y + 2 * font, swatch, 3 * font, layers[k].color);
    canvas.Text(3 * font + swatch + 2 * font, y, layers[k].name, font, kLegendText);
  }
  // The bar: a line with a tick at each end, on the baseline of the first line's text.
  const int bar_x = width - bar_width;
  const int bar_y = map_height + 2 * font + (Canvas::kGlyphHeight - 1) * font;
  canvas.FillRect(bar_x, bar_y, bar.length_px, font, kLegendText);
  canvas.FillRect(bar_x, bar_y - 3 * font, font, 3 * font, kLegendText);
  canvas.FillRect(bar_x + bar.length_px - font, bar_y - 3 * font, font, 3 * font, kLegendText);
  canvas.Text(bar_x + bar.length_px + 2 * font, map_height + 2 * font, bar.label, font,
              kLegendText);
  return canvas.Take();
}

}  // namespace slam::io
