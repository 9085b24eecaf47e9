#include "engine/io/map_yaml.hpp"

#include <png.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <csetjmp>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <map>
#include <optional>

#include "engine/cell_encoding.hpp"
#include "engine/io/text_fields.hpp"

namespace slam::io {
namespace {

namespace fs = std::filesystem;

// ---------------------------------------------------------------------------------------------
// map.yaml: flat `key: value` lines.

/// A map.yaml is a few lines; anything this big is not one.
constexpr uintmax_t kMaxYamlBytes = 1 << 20;

std::string_view Trim(std::string_view s) {
  const auto blank = [](char c) { return c == ' ' || c == '\t' || c == '\r'; };
  while (!s.empty() && blank(s.front())) s.remove_prefix(1);
  while (!s.empty() && blank(s.back())) s.remove_suffix(1);
  return s;
}

/// The text before a comment: '#' at the start or after a blank.
std::string_view StripComment(std::string_view s) {
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '#' && (i == 0 || s[i - 1] == ' ' || s[i - 1] == '\t')) return s.substr(0, i);
  }
  return s;
}

struct YamlValue {
  std::string text;  // unquoted, comment stripped
  bool quoted = false;
  int line = 0;
};

/// The top-level `key: value` pairs of `text`, or errors naming their line.
Result<std::map<std::string, YamlValue>> ParseFlatYaml(std::string_view text,
                                                       const std::string& path) {
  std::map<std::string, YamlValue> values;
  ConfigErrors errors;
  bool ended = false;
  ForEachLine(text, [&](size_t number, std::string_view raw) {
    const int line = static_cast<int>(number);
    if (ended) return;
    const std::string_view content = Trim(StripComment(raw));
    if (content.empty()) return;
    if (content == "---" && values.empty()) return;  // a document's start
    if (content == "...") {                          // its end
      ended = true;
      return;
    }
    if (raw.front() == ' ' || raw.front() == '\t') {
      errors.push_back(
          {"", "an indented line: map.yaml's keys are at the top level, one a line", line});
      return;
    }
    size_t colon = content.find(':');
    while (colon != std::string_view::npos && colon + 1 < content.size() &&
           content[colon + 1] != ' ' && content[colon + 1] != '\t') {
      colon = content.find(':', colon + 1);
    }
    if (colon == std::string_view::npos || colon == 0) {
      errors.push_back({"", "expected \"key: value\"", line});
      return;
    }
    const std::string key(Trim(content.substr(0, colon)));
    std::string_view value = Trim(content.substr(colon + 1));
    if (value.empty()) {
      errors.push_back({key, "no value (nested values are not read)", line});
      return;
    }
    YamlValue parsed;
    parsed.line = line;
    if (value.front() == '"' || value.front() == '\'') {
      // A quoted scalar: the comment was cut after a blank, so the quote must close the value.
      const std::string_view whole = Trim(raw.substr(raw.find(value.front(), colon)));
      const size_t close = whole.find(value.front(), 1);
      const std::string_view rest =
          close == std::string_view::npos ? "" : Trim(StripComment(whole.substr(close + 1)));
      if (close == std::string_view::npos || !rest.empty()) {
        errors.push_back({key, "a quoted value that does not end on its line", line});
        return;
      }
      parsed.text = std::string(whole.substr(1, close - 1));
      parsed.quoted = true;
    } else {
      parsed.text = std::string(value);
    }
    if (const auto [it, added] = values.emplace(key, parsed); !added) {
      errors.push_back(
          {key, "given twice (first on line " + std::to_string(it->second.line) + ")", line});
    }
  });
  if (!errors.empty()) return {std::move(errors), path};
  return values;
}

/// Errors gathered while reading the keys (each with its line), as map_server's keys ask.
class KeyReader {
 public:
  KeyReader(const std::map<std::string, YamlValue>& values, std::string path)
      : values_(values), path_(std::move(path)) {}

  const YamlValue* Find(const std::string& key, bool required = true) {
    const auto it = values_.find(key);
    if (it != values_.end()) return &it->second;
    if (required) errors_.push_back({"", path_ + ": missing key '" + key + "'", 0});
    return nullptr;
  }
  void Fail(const std::string& key, const YamlValue& value, const std::string& detail) {
    errors_.push_back({key, detail, value.line});
  }
  std::optional<double> Number(const std::string& key) {
    const YamlValue* v = Find(key);
    if (v == nullptr) return std::nullopt;
    double number = 0.0;
    if (v->quoted || !ParseFiniteDouble(v->text, number)) {
      Fail(key, *v, "'" + v->text + "' is not a finite number");
      return std::nullopt;
    }
    return number;
  }
  ConfigErrors& errors() { return errors_; }

 private:
  const std::map<std::string, YamlValue>& values_;
  std::string path_;
  ConfigErrors errors_;
};

// ---------------------------------------------------------------------------------------------
// Images.

Result<MapPixels> CheckedSize(int64_t width, int64_t height, const std::string& path) {
  if (width <= 0 || height <= 0 || width > kMaxMapImageSide || height > kMaxMapImageSide) {
    return Error(path + ": an image of " + std::to_string(width) + " x " + std::to_string(height) +
                 " pixels (each side must be 1 to " + std::to_string(kMaxMapImageSide) + ")");
  }
  MapPixels pixels;
  pixels.width = static_cast<int>(width);
  pixels.height = static_cast<int>(height);
  return pixels;
}

/// A binary PGM: "P5", width, height, maxval (blanks and '#' comments between), one blank,
/// then width * height bytes.
Result<MapPixels> DecodePgm(std::string_view bytes, const std::string& path) {
  size_t pos = 2;
  const auto blank = [](char c) {
    return c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\v' || c == '\f';
  };
  // A header field: at most 9 digits (no overflow; far above any side allowed).
  const auto field = [&]() -> std::optional<int64_t> {
    while (pos < bytes.size()) {
      const char c = bytes[pos];
      if (c == '#') {
        while (pos < bytes.size() && bytes[pos] != '\n') ++pos;
      } else if (blank(c)) {
        ++pos;
      } else {
        break;
      }
    }
    int64_t value = 0;
    size_t digits = 0;
    while (pos < bytes.size() && bytes[pos] >= '0' && bytes[pos] <= '9' && digits < 10) {
      value = value * 10 + (bytes[pos] - '0');
      ++pos;
      ++digits;
    }
    if (digits == 0 || digits > 9) return std::nullopt;
    return value;
  };
  const std::optional<int64_t> width = field(), height = field(), maxval = field();
  if (!width || !height || !maxval || pos >= bytes.size() || !blank(bytes[pos])) {
    return Error(path + ": a PGM header that does not parse (\"P5 width height maxval\")");
  }
  if (*maxval < 1 || *maxval > 255) {
    return Error(path + ": PGM maxval " + std::to_string(*maxval) +
                 " (only 8-bit PGM, maxval 1 to 255, is read)");
  }
  ++pos;  // the one blank after maxval
  Result<MapPixels> checked = CheckedSize(*width, *height, path);
  if (!checked.ok()) return checked;
  MapPixels pixels = std::move(checked).value();
  const size_t count = static_cast<size_t>(*width) * static_cast<size_t>(*height);
  if (bytes.size() - pos < count) {
    return Error(path + ": truncated: " + std::to_string(bytes.size() - pos) + " of " +
                 std::to_string(count) + " pixel bytes");
  }
  pixels.sum.resize(count);
  const auto* data = reinterpret_cast<const uint8_t*>(bytes.data() + pos);
  for (size_t i = 0; i < count; ++i) {
    const int64_t v = std::min<int64_t>(data[i], *maxval);
    pixels.sum[i] = static_cast<uint16_t>((v * 255 + *maxval / 2) / *maxval);
  }
  return pixels;
}

// PNG through libpng, from memory. libpng reports errors by longjmp: the frame holding setjmp
// (ReadPngRows) has only trivially destructible locals, and what it fills lives in the caller.

struct PngSource {
  std::string_view bytes;
  size_t pos = 0;
  char error[256] = "libpng failed";
};

void ReadFromMemory(png_structp png, png_bytep out, png_size_t length) {
  auto* source = static_cast<PngSource*>(png_get_io_ptr(png));
  if (length > source->bytes.size() - source->pos) png_error(png, "the file ends too soon");
  std::memcpy(out, source->bytes.data() + source->pos, length);
  source->pos += length;
}

void StoreReadError(png_structp png, png_const_charp message) {
  auto* error = static_cast<char*>(png_get_error_ptr(png));
  std::snprintf(error, 256, "%s", message);
  png_longjmp(png, 1);
}

void IgnoreReadWarning(png_structp, png_const_charp) {}

struct PngRows {
  png_uint_32 width = 0;
  png_uint_32 height = 0;
  int channels = 0;  // 1 grey, 2 grey + alpha, 3 RGB, 4 RGBA (8 bits each)
  std::vector<uint8_t> data;
  std::vector<png_bytep> rows;
};

/// Decodes every row as 8-bit channels; false (the error in the source) on failure.
bool ReadPngRows(png_structp png, png_infop info, PngSource* source, PngRows* out) {
  if (setjmp(png_jmpbuf(png))) return false;
  png_set_read_fn(png, source, ReadFromMemory);
  png_set_user_limits(png, static_cast<png_uint_32>(kMaxMapImageSide),
                      static_cast<png_uint_32>(kMaxMapImageSide));
  png_read_info(png, info);
  png_set_expand(png);  // palette to RGB, grey below 8 bits to 8, tRNS to alpha
  png_set_strip_16(png);
  png_set_interlace_handling(png);
  png_read_update_info(png, info);
  out->width = png_get_image_width(png, info);
  out->height = png_get_image_height(png, info);
  out->channels = png_get_channels(png, info);
  const size_t stride = png_get_rowbytes(png, info);
  if (out->channels < 1 || out->channels > 4 ||
      stride != size_t{out->width} * static_cast<size_t>(out->channels)) {
    png_error(png, "an unexpected pixel layout");
  }
  out->data.resize(stride * out->height);
  out->rows.resize(out->height);
  for (png_uint_32 y = 0; y < out->height; ++y) out->rows[y] = out->data.data() + y * stride;
  png_read_image(png, out->rows.data());
  png_read_end(png, nullptr);
  return true;
}

Result<MapPixels> DecodePng(std::string_view bytes, const std::string& path) {
  PngSource source;
  source.bytes = bytes;
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, source.error, StoreReadError,
                                           IgnoreReadWarning);
  if (png == nullptr) return Error(path + ": cannot initialise libpng");
  png_infop info = png_create_info_struct(png);
  if (info == nullptr) {
    png_destroy_read_struct(&png, nullptr, nullptr);
    return Error(path + ": cannot initialise libpng");
  }
  PngRows rows;
  const bool ok = ReadPngRows(png, info, &source, &rows);
  png_destroy_read_struct(&png, &info, nullptr);
  if (!ok) return Error(path + ": not a readable PNG: " + source.error);
  Result<MapPixels> checked = CheckedSize(rows.width, rows.height, path);
  if (!checked.ok()) return checked;
  MapPixels pixels = std::move(checked).value();
  const bool alpha = rows.channels == 2 || rows.channels == 4;
  pixels.colour_channels = rows.channels >= 3 ? 3 : 1;
  const size_t count = static_cast<size_t>(rows.width) * rows.height;
  pixels.sum.resize(count);
  if (alpha) pixels.alpha.resize(count);
  for (size_t i = 0; i < count; ++i) {
    const uint8_t* p = rows.data.data() + i * static_cast<size_t>(rows.channels);
    uint16_t sum = 0;
    for (int c = 0; c < pixels.colour_channels; ++c) sum = static_cast<uint16_t>(sum + p[c]);
    pixels.sum[i] = sum;
    if (alpha) pixels.alpha[i] = p[rows.channels - 1];
  }
  return pixels;
}

// ---------------------------------------------------------------------------------------------
// Files.

Result<std::string> ReadBoundedFile(const std::string& path, uintmax_t max_bytes,
                                    const std::string& what) {
  std::error_code ec;
  const fs::file_status status = fs::status(path, ec);
  if (ec || !fs::exists(status)) return Error(path + ": " + what + " not found");
  if (!fs::is_regular_file(status)) return Error(path + ": " + what + " is not a regular file");
  const uintmax_t size = fs::file_size(path, ec);
  if (ec) return Error(path + ": cannot read its size (" + ec.message() + ")");
  if (size > max_bytes) {
    return Error(path + ": " + std::to_string(size) + " bytes, too big for " + what + " (at most " +
                 std::to_string(max_bytes) + ")");
  }
  return ReadTextFile(path);
}

/// The encoded log odds of occupancy p, within the clamp.
LogOdds ClampedLogOdds(double p, int limit) {
  const double l = std::log(p / (1.0 - p));  // +-inf at 1 and 0: EncodeLogOdds clamps them
  return static_cast<LogOdds>(std::clamp<int>(EncodeLogOdds(l), -limit, limit));
}

/// Each pixel's cell value by its colour sum (alpha 255, or not looked at), and in scale mode
/// that of a pixel with alpha below 255 (unknown).
std::vector<LogOdds> CellValues(const MapYamlKeys& yaml, const MapPixels& pixels, int limit,
                                bool alpha_averaged) {
  const int channels = pixels.colour_channels + (alpha_averaged ? 1 : 0);
  std::vector<LogOdds> values(static_cast<size_t>(255 * channels + 1), 0);
  for (int sum = 0; sum <= 255 * channels; ++sum) {
    double c = static_cast<double>(sum) / channels;
    if (yaml.negate) c = 255.0 - c;
    LogOdds& v = values[static_cast<size_t>(sum)];
    if (yaml.mode == MapMode::kRaw) {
      if (c <= 100.0) v = ClampedLogOdds(c / 100.0, limit);
      continue;
    }
    const double p = (255.0 - c) / 255.0;
    if (p > yaml.occupied_thresh) {
      v = static_cast<LogOdds>(limit);
    } else if (p < yaml.free_thresh) {
      v = static_cast<LogOdds>(-limit);
    } else if (yaml.mode == MapMode::kScale) {
      v = ClampedLogOdds(p, limit);
    }
  }
  return values;
}

std::string Metres(double v) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.6g", v);
  return text;
}

}  // namespace

Result<MapYamlKeys> ParseMapYaml(std::string_view text, const std::string& path) {
  Result<std::map<std::string, YamlValue>> parsed = ParseFlatYaml(text, path);
  if (!parsed.ok()) return {parsed.errors(), path};
  const std::map<std::string, YamlValue>& values = parsed.value();
  KeyReader keys(values, path);
  MapYamlKeys yaml;
  if (const YamlValue* image = keys.Find("image")) {
    if (image->text.empty()) keys.Fail("image", *image, "an empty file name");
    yaml.image = image->text;
  }
  if (const std::optional<double> r = keys.Number("resolution")) {
    if (*r > 0.0) {
      yaml.resolution_m = *r;
    } else {
      keys.Fail("resolution", *keys.Find("resolution"), "must be above 0 (metres per pixel)");
    }
  }
  if (const YamlValue* origin = keys.Find("origin")) {
    const std::string_view v = origin->text;
    std::array<double, 3> xyz{};
    bool ok = !origin->quoted && v.size() >= 2 && v.front() == '[' && v.back() == ']';
    if (ok) {
      std::string_view inside = v.substr(1, v.size() - 2);
      size_t k = 0;
      while (ok) {
        const size_t comma = inside.find(',');
        const std::string_view item = Trim(inside.substr(0, comma));
        ok = k < 3 && ParseFiniteDouble(item, xyz[k]);
        ++k;
        if (comma == std::string_view::npos) break;
        inside.remove_prefix(comma + 1);
      }
      ok = ok && k == 3;
    }
    if (ok) {
      yaml.origin = {xyz[0], xyz[1], xyz[2]};
    } else {
      keys.Fail("origin", *origin,
                "'" + origin->text + "' is not [x, y, yaw] (three finite numbers on one line)");
    }
  }
  if (const YamlValue* negate = keys.Find("negate")) {
    if (negate->text == "0" || negate->text == "false" || negate->text == "False") {
      yaml.negate = false;
    } else if (negate->text == "1" || negate->text == "true" || negate->text == "True") {
      yaml.negate = true;
    } else {
      keys.Fail("negate", *negate, "'" + negate->text + "' is not 0 or 1");
    }
  }
  const auto threshold = [&](const std::string& key, double& out) {
    if (const std::optional<double> t = keys.Number(key)) {
      if (*t >= 0.0 && *t <= 1.0) {
        out = *t;
        return true;
      }
      keys.Fail(key, *keys.Find(key), "must be within 0 to 1 (an occupancy probability)");
    }
    return false;
  };
  const bool occupied = threshold("occupied_thresh", yaml.occupied_thresh);
  const bool free = threshold("free_thresh", yaml.free_thresh);
  if (occupied && free && !(yaml.free_thresh < yaml.occupied_thresh)) {
    keys.Fail("free_thresh", *keys.Find("free_thresh"),
              "must be below occupied_thresh (" + Metres(yaml.occupied_thresh) + ")");
  }
  if (const YamlValue* mode = keys.Find("mode", /*required=*/false)) {
    if (mode->text == "trinary") {
      yaml.mode = MapMode::kTrinary;
    } else if (mode->text == "scale") {
      yaml.mode = MapMode::kScale;
    } else if (mode->text == "raw") {
      yaml.mode = MapMode::kRaw;
    } else {
      keys.Fail("mode", *mode, "'" + mode->text + "' is not trinary, scale or raw");
    }
  }
  if (!keys.errors().empty()) return {std::move(keys.errors()), path};
  return yaml;
}

Result<MapPixels> DecodeMapImage(std::string_view bytes, const std::string& path) {
  static constexpr std::array<uint8_t, 8> kPngSignature{0x89, 'P',  'N',  'G',
                                                        '\r', '\n', 0x1a, '\n'};
  if (bytes.size() >= kPngSignature.size() &&
      std::equal(kPngSignature.begin(), kPngSignature.end(),
                 reinterpret_cast<const uint8_t*>(bytes.data()))) {
    return DecodePng(bytes, path);
  }
  if (bytes.size() >= 2 && bytes[0] == 'P' && bytes[1] == '5') return DecodePgm(bytes, path);
  if (bytes.size() >= 2 && bytes[0] == 'P' && bytes[1] >= '1' && bytes[1] <= '7') {
    return Error(path + ": a Netpbm image of type P" + std::string(1, bytes[1]) +
                 " (only binary PGM, P5, is read)");
  }
  return Error(path + ": neither a binary PGM (P5) nor a PNG");
}

Result<OccupancyGrid> LoadMapYaml(const std::string& yaml_path, const GridGeometry& geometry,
                                  int limit) {
  if (limit <= 0 || limit > kLogOddsLimit) {
    return Error("the cell clamp " + std::to_string(limit) + " is not within 1 to " +
                 std::to_string(kLogOddsLimit));
  }
  const Result<std::string> text = ReadBoundedFile(yaml_path, kMaxYamlBytes, "the map's yaml");
  if (!text.ok()) return {text.errors(), text.error_context()};
  const Result<MapYamlKeys> parsed = ParseMapYaml(text.value(), yaml_path);
  if (!parsed.ok()) return {parsed.errors(), parsed.error_context()};
  const MapYamlKeys& yaml = parsed.value();
  fs::path image_path(yaml.image);
  if (image_path.is_relative()) image_path = fs::path(yaml_path).parent_path() / image_path;
  const std::string image_name = image_path.string();
  // At most 4 bytes a pixel of the largest image (a PNG seldom is bigger than its pixels).
  constexpr uintmax_t kMaxImageBytes =
      uintmax_t{4} * kMaxMapImageSide * kMaxMapImageSide + (uintmax_t{1} << 20);
  const Result<std::string> bytes =
      ReadBoundedFile(image_name, kMaxImageBytes, "the map's image (" + yaml_path + ": image)");
  if (!bytes.ok()) return {bytes.errors(), bytes.error_context()};
  const Result<MapPixels> decoded = DecodeMapImage(bytes.value(), image_name);
  if (!decoded.ok()) return {decoded.errors(), decoded.error_context()};
  const MapPixels& pixels = decoded.value();

  // The image's corners in the world: all inside the map's bound.
  const double w_m = pixels.width * yaml.resolution_m, h_m = pixels.height * yaml.resolution_m;
  const double bound = kMapCellBound;  // in cells
  double lo_x = bound, lo_y = bound, hi_x = -bound, hi_y = -bound;
  bool inside = true;
  for (const Vec2& corner : {Vec2{0.0, 0.0}, Vec2{w_m, 0.0}, Vec2{0.0, h_m}, Vec2{w_m, h_m}}) {
    const Vec2 g = geometry.ToGrid(yaml.origin.Transform(corner));
    inside = inside && std::abs(g.x()) <= bound && std::abs(g.y()) <= bound;  // false for NaN
    lo_x = std::min(lo_x, g.x());
    lo_y = std::min(lo_y, g.y());
    hi_x = std::max(hi_x, g.x());
    hi_y = std::max(hi_y, g.y());
  }
  if (!inside) {
    return Error(yaml_path + ": the map (" + std::to_string(pixels.width) + " x " +
                 std::to_string(pixels.height) + " pixels of " + Metres(yaml.resolution_m) +
                 " m from (" + Metres(yaml.origin.x) + ", " + Metres(yaml.origin.y) +
                 ")) reaches beyond the map's bound (+-" +
                 Metres(kMapCellBound * geometry.resolution()) + " m at " +
                 Metres(geometry.resolution()) + " m cells)");
  }

  const bool alpha_averaged = yaml.mode == MapMode::kTrinary && !pixels.alpha.empty();
  const std::vector<LogOdds> values = CellValues(yaml, pixels, limit, alpha_averaged);
  OccupancyGrid grid(geometry, limit);
  grid.BeginWrite();
  // Each cell of the image's bounding box takes the pixel under its centre.
  const auto x0 = static_cast<int32_t>(std::max(-bound, std::floor(lo_x)));
  const auto y0 = static_cast<int32_t>(std::max(-bound, std::floor(lo_y)));
  const auto x1 = static_cast<int32_t>(std::min(bound, std::ceil(hi_x)));
  const auto y1 = static_cast<int32_t>(std::min(bound, std::ceil(hi_y)));
  const double c = std::cos(yaml.origin.theta), s = std::sin(yaml.origin.theta);
  const double inv = 1.0 / yaml.resolution_m;
  for (int32_t j = y0; j < y1; ++j) {
    Tile* tile = nullptr;
    TileIndex tile_index{};
    for (int32_t i = x0; i < x1; ++i) {
      const CellIndex cell{i, j};
      const Vec2 d = geometry.CellCenter(cell) - yaml.origin.translation();
      const double u = std::floor((c * d.x() + s * d.y()) * inv);
      const double v = std::floor((-s * d.x() + c * d.y()) * inv);
      if (!(u >= 0.0 && u < pixels.width && v >= 0.0 && v < pixels.height)) continue;
      const size_t k = static_cast<size_t>(pixels.height - 1 - static_cast<int>(v)) *
                           static_cast<size_t>(pixels.width) +
                       static_cast<size_t>(u);
      LogOdds value = 0;
      if (!alpha_averaged && yaml.mode == MapMode::kScale && !pixels.alpha.empty() &&
          pixels.alpha[k] < 255) {
        value = 0;
      } else {
        const int sum = pixels.sum[k] + (alpha_averaged ? pixels.alpha[k] : 0);
        value = values[static_cast<size_t>(sum)];
      }
      if (value == 0) continue;
      const TileIndex t = GridGeometry::TileOf(cell);
      if (tile == nullptr || !(t == tile_index)) {
        tile = &grid.MutableTile(t);  // tiles live on the heap: the reference outlives growth
        tile_index = t;
      }
      tile->cells[static_cast<size_t>(GridGeometry::OffsetInTile(cell))] = value;
    }
  }
  grid.RefreshSummaries();
  return grid;
}

}  // namespace slam::io
