// The lines of JSON pointers (engine/io/json_locate.hpp), and configuration errors that name the
// file and the line: FormatErrors, LoadRobot and LoadParams on edited copies of shipped files.

#include "engine/io/json_locate.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstddef>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "engine/config_error.hpp"
#include "engine/io/params_json.hpp"
#include "engine/io/robot_json.hpp"
#include "tests/test_support.hpp"

namespace slam::io {
namespace {

namespace fs = std::filesystem;
using testing::TempDir;

const fs::path kConfigDir = fs::path(SLAM_SOURCE_DIR) / "config";

// --- LineOfPointer -----------------------------------------------------------------------------

TEST(LineOfPointer, NestedObjectsAndArrays) {
  const std::string text =
      "{\n"                     // 1
      "  \"a\": {\n"            // 2
      "    \"b\": [\n"          // 3
      "      1,\n"              // 4
      "      {\"c\": true},\n"  // 5
      "      [null,\n"          // 6
      "       \"x\"]\n"         // 7
      "    ]\n"                 // 8
      "  },\n"                  // 9
      "  \"d\": -1.5e3\n"       // 10
      "}\n";                    // 11
  EXPECT_EQ(LineOfPointer(text, ""), 1);
  EXPECT_EQ(LineOfPointer(text, "/a"), 2);
  EXPECT_EQ(LineOfPointer(text, "/a/b"), 3);
  EXPECT_EQ(LineOfPointer(text, "/a/b/0"), 4);
  EXPECT_EQ(LineOfPointer(text, "/a/b/1"), 5);
  EXPECT_EQ(LineOfPointer(text, "/a/b/1/c"), 5);
  EXPECT_EQ(LineOfPointer(text, "/a/b/2"), 6);
  EXPECT_EQ(LineOfPointer(text, "/a/b/2/0"), 6);
  EXPECT_EQ(LineOfPointer(text, "/a/b/2/1"), 7);
  EXPECT_EQ(LineOfPointer(text, "/d"), 10);

  // Names nothing: past the end, absent keys, leading zeros, "-", members of scalars.
  for (const char* pointer : {"/a/b/3", "/a/c", "/x", "/a/b/01", "/a/b/-", "/a/b/2/1/0", "/d/0",
                              "/a/b/1/c/d", "/0", "/a/0"}) {
    EXPECT_EQ(LineOfPointer(text, pointer), std::nullopt) << pointer;
  }
  // Malformed pointers.
  for (const char* pointer : {"a", "a/b", "/a~2", "/a~", "/~"}) {
    EXPECT_EQ(LineOfPointer(text, pointer), std::nullopt) << pointer;
    EXPECT_EQ(LineOfNearestValue(text, pointer), std::nullopt) << pointer;
  }
  // The nearest value that exists: the object that lacks a key, the array that is too short.
  EXPECT_EQ(LineOfNearestValue(text, "/a/b/2/1"), 7);
  EXPECT_EQ(LineOfNearestValue(text, "/a/b/3"), 3);
  EXPECT_EQ(LineOfNearestValue(text, "/a/b/1/missing"), 5);
  EXPECT_EQ(LineOfNearestValue(text, "/a/zzz/0"), 2);
  EXPECT_EQ(LineOfNearestValue(text, "/x/y"), 1);
  EXPECT_EQ(LineOfNearestValue(text, "/d/0"), 10);
}

TEST(LineOfPointer, EscapedKeys) {
  const std::string text =
      "{\n"
      "  \"a/b\": 1,\n"             // 2
      "  \"m~n\": 2,\n"             // 3
      "  \"q\\\"r\": 3,\n"          // 4: "q\"r"
      "  \"back\\\\slash\": 4,\n"   // 5: "back\\slash"
      "  \"\\u0041\\u00e9\": 5,\n"  // 6: "\u0041\u00e9" is "Aé"
      "  \"\": {\"\": 6},\n"        // 7: the empty key
      "  \"\\ud83d\\ude00\": 7,\n"  // 8: a surrogate pair, U+1F600
      "  \"a\": {\"b\": 8}\n"       // 9
      "}";
  EXPECT_EQ(LineOfPointer(text, "/a~1b"), 2);
  EXPECT_EQ(LineOfPointer(text, "/m~0n"), 3);
  EXPECT_EQ(LineOfPointer(text, "/q\"r"), 4);
  EXPECT_EQ(LineOfPointer(text, "/back\\slash"), 5);
  EXPECT_EQ(LineOfPointer(text, "/A\xC3\xA9"), 6);
  EXPECT_EQ(LineOfPointer(text, "/"), 7);
  EXPECT_EQ(LineOfPointer(text, "//"), 7);
  EXPECT_EQ(LineOfPointer(text, "/\xF0\x9F\x98\x80"), 8);
  EXPECT_EQ(LineOfPointer(text, "/a/b"), 9);                // the nested key, not "a/b"
  EXPECT_EQ(LineOfPointer(text, "/a~01b"), std::nullopt);   // "a~1b"
  EXPECT_EQ(LineOfPointer(text, "/q\\\"r"), std::nullopt);  // keys compare decoded
}

TEST(LineOfPointer, StringsWithStructuralCharactersAndNewlines) {
  const std::string text =
      "{\n"
      "  \"s\": \"{[:,]}\\\"\",\n"             // 2: "{[:,]}\""
      "  \"t{:\": \"line\\nbreak { \\\\\",\n"  // 3: an escaped newline, a backslash at the end
      "  \"u\": [\n"                           // 4
      "    \"]\", \"}\", \"\\\"]\"\n"          // 5
      "  ],\n"
      "  \"target\": \"/\"\n"  // 7
      "}\n";
  EXPECT_EQ(LineOfPointer(text, "/s"), 2);
  EXPECT_EQ(LineOfPointer(text, "/t{:"), 3);
  EXPECT_EQ(LineOfPointer(text, "/u"), 4);
  EXPECT_EQ(LineOfPointer(text, "/u/2"), 5);
  EXPECT_EQ(LineOfPointer(text, "/target"), 7);
  EXPECT_EQ(LineOfPointer(text, "/u/3"), std::nullopt);
}

TEST(LineOfPointer, MultiLineLayouts) {
  // CRLF line ends, a key and its value on different lines (the value's line counts), a byte
  // order mark, scalars at the root, blank lines before the root.
  EXPECT_EQ(LineOfPointer("{\r\n  \"a\": 1,\r\n  \"b\": 2\r\n}\r\n", "/b"), 3);
  EXPECT_EQ(LineOfPointer("{\n  \"k\":\n    7\n}", "/k"), 3);
  EXPECT_EQ(LineOfPointer("\xEF\xBB\xBF{\"a\":\n1}", "/a"), 2);
  EXPECT_EQ(LineOfPointer("42", ""), 1);
  EXPECT_EQ(LineOfPointer("\n\n  \"x\"  \n", ""), 3);
  EXPECT_EQ(LineOfPointer("[\n]", "/0"), std::nullopt);
  EXPECT_EQ(LineOfNearestValue("[\n]", "/0"), 1);
  // A whole line per element of a long array.
  std::string lines = "[";
  for (int i = 0; i < 1000; ++i) lines += (i ? ",\n" : "\n") + std::to_string(i);
  lines += "\n]";
  EXPECT_EQ(LineOfPointer(lines, "/0"), 2);
  EXPECT_EQ(LineOfPointer(lines, "/999"), 1001);
  EXPECT_EQ(LineOfPointer(lines, "/1000"), std::nullopt);
}

TEST(LineOfPointer, DuplicateKeysResolveToTheLastOccurrence) {
  // nlohmann keeps the last value of a duplicate key, so errors about it point there.
  EXPECT_EQ(LineOfPointer("{\n\"a\": 1,\n\"a\": 2\n}", "/a"), 3);
  const std::string text = "{\n\"a\": {\"b\": 1},\n\"a\": {}\n}";
  EXPECT_EQ(LineOfPointer(text, "/a/b"), std::nullopt);  // the kept "a" has no "b"
  EXPECT_EQ(LineOfNearestValue(text, "/a/b"), 3);
  EXPECT_EQ(LineOfPointer("{\n\"a\": {},\n\"a\": {\n\"b\": 1}}", "/a/b"), 4);
}

TEST(LineOfPointer, MalformedTextGivesNothing) {
  for (const std::string text : {"",
                                 "   \n",
                                 "{",
                                 "[",
                                 "{\"a\"",
                                 "{\"a\":",
                                 "{\"a\": 1",
                                 "{\"a\": 1,}",
                                 "[1,]",
                                 "[1 2]",
                                 "{\"a\" 1}",
                                 "{1: 2}",
                                 "{\"a\": 1 \"b\": 2}",
                                 "tru",
                                 "nul",
                                 "falsey",
                                 "01",
                                 "1.",
                                 "-",
                                 "1e",
                                 "1e+",
                                 ".5",
                                 "+1",
                                 "\"abc",
                                 "\"\\x\"",
                                 "\"\\u12\"",
                                 "\"\\u12g4\"",
                                 "\"\\ud800\"",
                                 "\"\\udc00\"",
                                 "\"\\ud800\\u0041\"",
                                 "\"a\nb\"",
                                 "\"a\tb\"",
                                 "\"\\",
                                 "{} {}",
                                 "1 2",
                                 "]",
                                 "}",
                                 "[}",
                                 "{]",
                                 "{\"a\": 1}}",
                                 "[1]]",
                                 "\xEF\xBB",
                                 "\xEF\xBB\xBF",
                                 "{'a': 1}",
                                 "[NaN]",
                                 "/* c */ 1",
                                 "{\"a\": 1}\n//"}) {
    EXPECT_EQ(LineOfNearestValue(text, ""), std::nullopt) << text;
    EXPECT_EQ(LineOfPointer(text, "/a"), std::nullopt) << text;
  }
  // Every truncation of a document is malformed, even when the pointer was found before the cut.
  const std::string document = "{\"a\": [1, {\"b\": \"x\\\"y\"}, -2.5e-3, true, null], \"c\": {}}";
  ASSERT_EQ(LineOfPointer(document, "/a/1/b"), 1);
  for (std::size_t size = 0; size < document.size(); ++size) {
    EXPECT_EQ(LineOfNearestValue(document.substr(0, size), "/a/1/b"), std::nullopt) << size;
  }
}

TEST(LineOfPointer, AcceptsExactlyWhatNlohmannAccepts) {
  // Seeded mutations of a document (JSON's own punctuation, so the structure breaks in every
  // way): a text locates its root exactly when nlohmann parses it.
  const std::string document =
      "{\"a\": [1, {\"b\": \"x\\\"y\"}, -2.5e-3, true, null],\n \"c\": {\"d\": [[]], \"e\": \"\"}}";
  const std::string alphabet = "{}[]:,\"\\ 0123456789.eE+-tfnul\nabx/";
  std::mt19937 random(12345);
  int accepted = 0;
  for (int trial = 0; trial < 20000; ++trial) {
    std::string text = document;
    const int edits = 1 + static_cast<int>(random() % 3);
    for (int e = 0; e < edits && !text.empty(); ++e) {
      const std::size_t at = random() % text.size();
      const char c = alphabet[random() % alphabet.size()];
      switch (random() % 3) {
        case 0:
          text[at] = c;
          break;
        case 1:
          text.insert(text.begin() + static_cast<std::ptrdiff_t>(at), c);
          break;
        default:
          text.erase(at, 1);
          break;
      }
    }
    const bool valid = nlohmann::json::accept(text);
    accepted += valid ? 1 : 0;
    ASSERT_EQ(LineOfNearestValue(text, "/a/1/b").has_value(), valid) << text;
  }
  EXPECT_GT(accepted, 100);  // the oracle saw both answers
}

TEST(LineOfPointer, DeepNestingNeitherOverflowsNorSlows) {
  constexpr std::size_t kDepth = 100000;
  const std::string open(kDepth, '[');
  EXPECT_EQ(LineOfPointer(open, ""), std::nullopt);  // never closed
  EXPECT_EQ(LineOfNearestValue(open, "/0/0"), std::nullopt);

  const std::string nested = open + "\n7\n" + std::string(kDepth, ']');
  std::string innermost;
  for (std::size_t i = 0; i < kDepth; ++i) innermost += "/0";
  EXPECT_EQ(LineOfPointer(nested, ""), 1);
  EXPECT_EQ(LineOfPointer(nested, "/0/0/0"), 1);
  EXPECT_EQ(LineOfPointer(nested, innermost), 2);  // the 7
  EXPECT_EQ(LineOfPointer(nested, innermost + "/0"), std::nullopt);
  EXPECT_EQ(LineOfNearestValue(nested, innermost + "/0"), 2);
  EXPECT_EQ(LineOfPointer(nested.substr(0, nested.size() - 1), ""), std::nullopt);

  const std::string objects = [] {
    std::string text;
    for (std::size_t i = 0; i < kDepth; ++i) text += "{\"k\":";
    return text + "1" + std::string(kDepth, '}');
  }();
  EXPECT_EQ(LineOfPointer(objects, "/k/k/k"), 1);
  EXPECT_EQ(LineOfPointer(objects, "/k/x"), std::nullopt);
}

// --- Messages ----------------------------------------------------------------------------------

TEST(ConfigErrorsWithLines, FormatNamesTheContextAndTheLine) {
  const ConfigErrors errors = {{"/a", "bad", 7}, {"", "whole document", 2}, {"/b", "no line"}};
  EXPECT_EQ(FormatErrors(errors, "f.json"),
            "f.json:7: /a: bad\nf.json:2: whole document\nf.json#/b: no line");
  EXPECT_EQ(FormatErrors(errors), "line 7: /a: bad\nline 2: whole document\n/b: no line");
  EXPECT_EQ(FormatError({"/a~1b", "x", 3}, "w.json"), "w.json:3: /a~1b: x");
}

// --- Loaders: copies of the shipped files, edited on known lines --------------------------------

/// The lines of a file, without their '\n'.
std::vector<std::string> ReadLines(const fs::path& path) {
  std::ifstream in(path);
  std::vector<std::string> lines;
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  return lines;
}

void WriteLines(const std::string& path, const std::vector<std::string>& lines) {
  std::ofstream out(path, std::ios::binary);
  for (const std::string& line : lines) out << line << '\n';
}

/// The index of the first line containing `needle` (ADD_FAILURE and 0 when none).
std::size_t IndexOf(const std::vector<std::string>& lines, const std::string& needle) {
  for (std::size_t i = 0; i < lines.size(); ++i) {
    if (lines[i].find(needle) != std::string::npos) return i;
  }
  ADD_FAILURE() << "no line contains " << needle;
  return 0;
}

/// "path:line: " as a message starts.
std::string At(const std::string& path, std::size_t index) {
  return path + ":" + std::to_string(index + 1) + ": ";
}

bool Contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

class RobotFileErrors : public ::testing::Test {
 protected:
  void SetUp() override {
    lines_ = ReadLines(kConfigDir / "marxbot.robot.json");
    ASSERT_GT(lines_.size(), 20u);
  }
  /// LoadRobot on the edited lines; the message (the load must fail).
  std::string Load() {
    WriteLines(path_, lines_);
    const Result<RobotDescription> robot = LoadRobot(path_);
    EXPECT_FALSE(robot.ok());
    return robot.Message();
  }

  TempDir dir_{"robot"};
  const std::string path_ = dir_.File("marxbot.robot.json");
  std::vector<std::string> lines_;
};

TEST_F(RobotFileErrors, UnknownKey) {
  const std::size_t at = IndexOf(lines_, "\"event\": 16,") + 1;
  lines_.insert(lines_.begin() + static_cast<std::ptrdiff_t>(at), "    \"foo\": 1,");
  const std::string message = Load();
  EXPECT_EQ(message, At(path_, at) + "/base/foo: unknown key");
  EXPECT_PRED2(Contains, message, "robot.json:" + std::to_string(at + 1) + ":");
}

TEST_F(RobotFileErrors, WrongType) {
  const std::size_t at = IndexOf(lines_, "\"ticks_per_m\": 11375,");
  lines_[at] = "    \"ticks_per_m\": \"11375\",";
  EXPECT_EQ(Load(), At(path_, at) + "/base/ticks_per_m: expected a number, got string");
}

TEST_F(RobotFileErrors, DeepValueAndRangeError) {
  // One calibration point per line: the line of /sensor_types/short/calibration/3/1.
  const std::size_t at = IndexOf(lines_, "[602, 0.055],");
  lines_[at] = "        [602, null],";
  EXPECT_EQ(Load(),
            At(path_, at) + "/sensor_types/short/calibration/3/1: expected a number, got null");
  lines_ = ReadLines(kConfigDir / "marxbot.robot.json");
  const std::size_t node = IndexOf(lines_, "\"node\": 2,");
  lines_[node] = "    \"node\": 300,";
  EXPECT_EQ(Load(), At(path_, node) + "/scanner/node: 300 is outside [0, 255]");
}

TEST_F(RobotFileErrors, MissingKeyNamesTheLineOfItsObject) {
  const std::size_t base = IndexOf(lines_, "\"base\": {");
  lines_.erase(lines_.begin() + static_cast<std::ptrdiff_t>(IndexOf(lines_, "track_width_m")));
  EXPECT_EQ(Load(), At(path_, base) + "/base/track_width_m: missing required key");
}

TEST_F(RobotFileErrors, DuplicateKeyNamesTheLineOfTheSecond) {
  const std::size_t at = IndexOf(lines_, "\"track_width_m\": 0.15,") + 1;
  lines_.insert(lines_.begin() + static_cast<std::ptrdiff_t>(at), "    \"node\": 1,");
  EXPECT_EQ(Load(), At(path_, at) + "/base/node: duplicate key");
}

TEST_F(RobotFileErrors, RootOfTheWrongTypeAndSyntaxErrors) {
  lines_ = {"", "[1]"};
  EXPECT_EQ(Load(), path_ + ":2: expected an object, got array");
  // Syntax errors keep nlohmann's own "line L, column C" message.
  lines_ = {"{", "  \"name\": \"marxbot\",", "  \"base\": {\"node\": 1,}", "}"};
  const std::string message = Load();
  EXPECT_EQ(message.rfind(path_ + ": parse error at line 3, column ", 0), 0u) << message;
}

TEST(ParamsFileErrors, UnknownKeyAndWrongType) {
  TempDir dir("params");
  const std::string path = dir.File("params.json");
  std::vector<std::string> lines = ReadLines(kConfigDir / "params.default.json");
  const std::size_t particles = IndexOf(lines, "\"particles\"");
  lines[particles] = "  \"particles\": \"many\"";
  lines.insert(lines.begin() + 1, "  \"particels\": 3,");
  WriteLines(path, lines);
  const Result<SlamParams> params = LoadParams(path);
  ASSERT_FALSE(params.ok());
  // Errors come in the order of the reader: the known keys, then the unknown ones.
  EXPECT_EQ(params.Message(), At(path, particles + 1) +
                                  "/particles: expected an integer, got string\n" + At(path, 1) +
                                  "/particels: unknown key");
  EXPECT_PRED2(Contains, params.Message(), "params.json:2: /particels");
}

}  // namespace
}  // namespace slam::io
