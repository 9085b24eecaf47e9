#pragma once
// Independent readers of the map files the project writes, shared by the test suites: a binary
// PGM parser, a flat YAML reader (map_server's map.yaml) and libpng's own PNG decoder.

#include <png.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cstdint>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "engine/io/map_image.hpp"

namespace slam::testing {

/// The whole file ("" when it cannot be read).
inline std::string ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

/// A binary PGM (P5) file: header fields and the pixel bytes.
struct Pgm {
  std::string magic;
  int width = 0, height = 0, maxval = 0;
  std::string pixels;
};

inline Pgm ParsePgm(const std::string& bytes) {
  Pgm pgm;
  size_t pos = 0;
  const auto token = [&] {
    while (pos < bytes.size()) {
      if (bytes[pos] == '#') {
        while (pos < bytes.size() && bytes[pos] != '\n') ++pos;
      } else if (std::isspace(static_cast<unsigned char>(bytes[pos]))) {
        ++pos;
      } else {
        break;
      }
    }
    const size_t start = pos;
    while (pos < bytes.size() && !std::isspace(static_cast<unsigned char>(bytes[pos]))) ++pos;
    return bytes.substr(start, pos - start);
  };
  pgm.magic = token();
  pgm.width = std::stoi(token());
  pgm.height = std::stoi(token());
  pgm.maxval = std::stoi(token());
  pgm.pixels = bytes.substr(pos + 1);  // exactly one whitespace after maxval
  return pgm;
}

/// "key: value" lines of a flat YAML file.
inline std::map<std::string, std::string> ParseYaml(const std::string& text) {
  std::map<std::string, std::string> values;
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    const size_t colon = line.find(": ");
    if (colon != std::string::npos) values[line.substr(0, colon)] = line.substr(colon + 2);
  }
  return values;
}

/// An RGB image decoded by libpng's simplified API; width 0 on failure.
inline io::RgbImage ReadPng(const std::string& path) {
  png_image png{};
  png.version = PNG_IMAGE_VERSION;
  io::RgbImage image;
  if (!png_image_begin_read_from_file(&png, path.c_str())) return image;
  png.format = PNG_FORMAT_RGB;
  std::vector<uint8_t> pixels(PNG_IMAGE_SIZE(png));
  if (!png_image_finish_read(&png, nullptr, pixels.data(), 0, nullptr)) return image;
  image.width = static_cast<int>(png.width);
  image.height = static_cast<int>(png.height);
  image.rgb = std::move(pixels);
  return image;
}

inline std::array<uint8_t, 3> Pixel(const io::RgbImage& image, int x, int y) {
  const size_t i =
      (static_cast<size_t>(y) * static_cast<size_t>(image.width) + static_cast<size_t>(x)) * 3;
  return {image.rgb[i], image.rgb[i + 1], image.rgb[i + 2]};
}

/// Pixels of exactly `color` in [x0, x1) x [y0, y1).
inline int CountColor(const io::RgbImage& image, int x0, int y0, int x1, int y1,
                      const std::array<uint8_t, 3>& color) {
  int n = 0;
  for (int y = std::max(0, y0); y < std::min(image.height, y1); ++y) {
    for (int x = std::max(0, x0); x < std::min(image.width, x1); ++x)
      n += Pixel(image, x, y) == color;
  }
  return n;
}

}  // namespace slam::testing
