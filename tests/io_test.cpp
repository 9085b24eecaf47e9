// The JSON adapters of engine/io: every shipped config file loads, round trips are exact, and
// every kind of bad input is reported with the JSON pointer of the culprit. map_server maps
// (map_yaml.hpp): the project's own export reads back cell for cell, resampled and rotated maps
// land where they should, and every bad map.yaml or image is an error naming file and line.

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "engine/cell_encoding.hpp"
#include "engine/config_error.hpp"
#include "engine/io/map_image.hpp"
#include "engine/io/map_yaml.hpp"
#include "engine/io/params_json.hpp"
#include "engine/io/robot_json.hpp"
#include "engine/params.hpp"
#include "engine/robot.hpp"
#include "tests/test_support.hpp"

namespace slam::io {
namespace {

namespace fs = std::filesystem;
using testing::TempDir;
using Json = nlohmann::json;

const fs::path kSourceDir = SLAM_SOURCE_DIR;
const fs::path kConfigDir = kSourceDir / "config";
const std::string kDefaultRobot = (kConfigDir / "marxbot.robot.json").string();
const std::string kDefaultParams = (kConfigDir / "params.default.json").string();

bool EndsWith(const std::string& text, const std::string& suffix) {
  return text.size() >= suffix.size() &&
         text.compare(text.size() - suffix.size(), suffix.size(), suffix) == 0;
}

// The pointers of a list of errors, for readable assertions.
std::vector<std::string> Pointers(const ConfigErrors& errors) {
  std::vector<std::string> pointers;
  for (const ConfigError& error : errors) pointers.push_back(error.pointer);
  return pointers;
}

bool HasPointer(const ConfigErrors& errors, const std::string& pointer) {
  return std::any_of(errors.begin(), errors.end(),
                     [&](const ConfigError& e) { return e.pointer == pointer; });
}

// The detail of the first error at `pointer`, or "" when there is none.
std::string DetailAt(const ConfigErrors& errors, const std::string& pointer) {
  for (const ConfigError& error : errors) {
    if (error.pointer == pointer) return error.detail;
  }
  return "";
}

Json DefaultRobotJson() {
  std::ifstream in(kDefaultRobot);
  return Json::parse(in);
}

void WriteText(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

void ExpectSameRobot(const RobotDescription& a, const RobotDescription& b) {
  EXPECT_EQ(a.name, b.name);
  EXPECT_EQ(a.base.node, b.base.node);
  EXPECT_EQ(a.base.event, b.base.event);
  EXPECT_EQ(a.base.track_width_m, b.base.track_width_m);
  EXPECT_EQ(a.base.ticks_per_m, b.base.ticks_per_m);
  EXPECT_EQ(a.base.gyro_unit_dps, b.base.gyro_unit_dps);
  EXPECT_EQ(a.scanner.node, b.scanner.node);
  EXPECT_EQ(a.scanner.event, b.scanner.event);
  EXPECT_EQ(a.scanner.sample_rate_hz, b.scanner.sample_rate_hz);
  EXPECT_EQ(a.scanner.mount_radius_m, b.scanner.mount_radius_m);
  ASSERT_EQ(a.scanner.sensors.size(), b.scanner.sensors.size());
  for (std::size_t i = 0; i < a.scanner.sensors.size(); ++i) {
    EXPECT_EQ(a.scanner.sensors[i].type, b.scanner.sensors[i].type) << i;
    EXPECT_EQ(a.scanner.sensors[i].angle_deg, b.scanner.sensors[i].angle_deg) << i;
  }
  ASSERT_EQ(a.sensor_types.size(), b.sensor_types.size());
  for (const auto& [name, ta] : a.sensor_types) {
    ASSERT_EQ(b.sensor_types.count(name), 1u) << name;
    const SensorTypeDescription& tb = b.sensor_types.at(name);
    EXPECT_EQ(ta.model, tb.model) << name;
    EXPECT_EQ(ta.range_min_m, tb.range_min_m) << name;
    EXPECT_EQ(ta.range_max_m, tb.range_max_m) << name;
    EXPECT_EQ(ta.use_min_m, tb.use_min_m) << name;
    EXPECT_EQ(ta.use_max_m, tb.use_max_m) << name;
    EXPECT_EQ(ta.sigma_m, tb.sigma_m) << name;
    ASSERT_EQ(ta.calibration.size(), tb.calibration.size()) << name;
    for (std::size_t i = 0; i < ta.calibration.size(); ++i) {
      EXPECT_EQ(ta.calibration[i].raw, tb.calibration[i].raw) << name << " " << i;
      EXPECT_EQ(ta.calibration[i].distance_m, tb.calibration[i].distance_m) << name << " " << i;
    }
  }
}

// Robot JSON with one value replaced (or removed when `value` is discarded).
Result<RobotDescription> RobotWith(const std::string& pointer, const Json& value) {
  Json json = DefaultRobotJson();
  json[Json::json_pointer(pointer)] = value;
  return RobotFromJson(json);
}

Result<RobotDescription> RobotWithout(const std::string& pointer) {
  Json json = DefaultRobotJson();
  const Json::json_pointer ptr(pointer);
  json[ptr.parent_pointer()].erase(ptr.back());
  return RobotFromJson(json);
}

// --- Shipped configuration ---------------------------------------------------------------------

TEST(ShippedConfig, EveryJsonFileUnderConfigLoads) {
  ASSERT_TRUE(fs::is_directory(kConfigDir)) << kConfigDir;
  int robots = 0;
  int params = 0;
  for (const fs::directory_entry& entry : fs::recursive_directory_iterator(kConfigDir)) {
    if (!entry.is_regular_file() || entry.path().extension() != ".json") continue;
    const std::string path = entry.path().string();
    const std::string name = entry.path().filename().string();
    SCOPED_TRACE(path);
    if (EndsWith(name, ".robot.json")) {
      const Result<RobotDescription> robot = LoadRobot(path);
      EXPECT_TRUE(robot.ok()) << robot.Message();
      ++robots;
    } else if (name.rfind("params", 0) == 0 || entry.path().parent_path().filename() == "params" ||
               entry.path().parent_path() == kConfigDir / "params" / "laser") {
      // params*.json, and the shipped sets config/params/<budget>.json and
      // config/params/laser/<budget>.json (ParamsCatalogTest checks that the compiled-in copies
      // are these files).
      const Result<SlamParams> loaded = LoadParams(path);
      EXPECT_TRUE(loaded.ok()) << loaded.Message();
      ++params;
    } else {
      ADD_FAILURE() << "unknown kind of config file (expected *.robot.json, params*.json, "
                       "params/<budget>.json or params/laser/<budget>.json)";
    }
  }
  EXPECT_GE(robots, 1);
  EXPECT_GE(params, 1);
}

TEST(ShippedConfig, DefaultRobotMatchesDesign) {
  const Result<RobotDescription> loaded = LoadRobot(kDefaultRobot);
  ASSERT_TRUE(loaded.ok()) << loaded.Message();
  const RobotDescription& robot = loaded.value();
  EXPECT_EQ(robot.name, "marxbot");
  EXPECT_EQ(robot.base.node, 1);
  EXPECT_EQ(robot.base.event, 0x10);
  EXPECT_EQ(robot.scanner.node, 2);
  EXPECT_EQ(robot.scanner.event, 0x20);
  ASSERT_EQ(robot.scanner.sensors.size(), 4u);
  EXPECT_EQ(robot.scanner.sensors[0].type, "short");
  EXPECT_EQ(robot.scanner.sensors[1].type, "long");
  EXPECT_EQ(robot.scanner.sensors[3].angle_deg, 270.0);

  // docs/design.md section 5: 4 cm reads 822 on the short sensor, 20 cm reads 760 on the long one.
  const SensorTypeDescription& short_type = robot.sensor_types.at("short");
  const SensorTypeDescription& long_type = robot.sensor_types.at("long");
  ASSERT_FALSE(short_type.calibration.empty());
  ASSERT_FALSE(long_type.calibration.empty());
  EXPECT_EQ(short_type.calibration.front().raw, 822);
  EXPECT_DOUBLE_EQ(short_type.calibration.front().distance_m, 0.04);
  EXPECT_EQ(long_type.calibration.front().raw, 760);
  EXPECT_DOUBLE_EQ(long_type.calibration.front().distance_m, 0.20);
  EXPECT_DOUBLE_EQ(short_type.calibration.back().distance_m, 0.35);
  EXPECT_DOUBLE_EQ(long_type.calibration.back().distance_m, 1.50);
  EXPECT_EQ(short_type.sigma_m, (std::array<double, 3>{0.003, 0.0, 0.02}));
  EXPECT_EQ(long_type.sigma_m, (std::array<double, 3>{0.005, 0.0, 0.02}));
}

TEST(ShippedConfig, DefaultParamsAreTableII) {
  const Result<SlamParams> loaded = LoadParams(kDefaultParams);
  ASSERT_TRUE(loaded.ok()) << loaded.Message();
  EXPECT_EQ(loaded.value(), SlamParams{});
  EXPECT_EQ(ParamsToJson(loaded.value()), Json::parse(std::ifstream(kDefaultParams)));
}

// --- Robot: round trip and errors --------------------------------------------------------------

TEST(RobotJson, RoundTripIsExact) {
  const Result<RobotDescription> loaded = LoadRobot(kDefaultRobot);
  ASSERT_TRUE(loaded.ok()) << loaded.Message();
  RobotDescription robot = loaded.value();
  robot.name = "edited";
  robot.scanner.mount_radius_m = 0.1 + 0.2;  // a double whose shortest text is long
  robot.sensor_types.at("long").sigma_m = {0.004, 0.001, 0.03};
  robot.sensor_types.at("short").calibration.back().distance_m = std::nextafter(0.35, 1.0);

  const Json json = RobotToJson(robot);
  const Result<RobotDescription> again = RobotFromJson(Json::parse(json.dump()));
  ASSERT_TRUE(again.ok()) << again.Message();
  ExpectSameRobot(robot, again.value());
  EXPECT_EQ(RobotToJson(again.value()), json);
}

TEST(RobotJson, ShippedFileEqualsItsRoundTrip) {
  // The shipped file states every key that RobotToJson writes: nothing is hidden in defaults.
  EXPECT_EQ(RobotToJson(LoadRobot(kDefaultRobot).value()), DefaultRobotJson());
}

TEST(RobotJson, SigmaIsOptional) {
  Json json = DefaultRobotJson();
  json["sensor_types"]["long"].erase("sigma_m");
  const Result<RobotDescription> robot = RobotFromJson(json);
  ASSERT_TRUE(robot.ok()) << robot.Message();
  EXPECT_EQ(robot.value().sensor_types.at("long").sigma_m, SensorTypeDescription{}.sigma_m);
}

TEST(RobotJson, MaxSpeedIsOptionalBoundedAndWrittenWhenGiven) {
  const Result<RobotDescription> plain = RobotFromJson(DefaultRobotJson());
  ASSERT_TRUE(plain.ok()) << plain.Message();
  EXPECT_EQ(plain.value().base.max_speed_m_s, BaseDescription{}.max_speed_m_s);
  EXPECT_FALSE(RobotToJson(plain.value())["base"].contains("max_speed_m_s"));

  const Result<RobotDescription> slow = RobotWith("/base/max_speed_m_s", 0.3);
  ASSERT_TRUE(slow.ok()) << slow.Message();
  EXPECT_EQ(slow.value().base.max_speed_m_s, 0.3);
  EXPECT_EQ(RobotToJson(slow.value())["base"]["max_speed_m_s"], 0.3);
  for (const double bad : {0.0, -1.0, 25.0, 1e6}) {
    EXPECT_EQ(Pointers(RobotWith("/base/max_speed_m_s", bad).errors()),
              std::vector<std::string>{"/base/max_speed_m_s"})
        << bad;
  }
}

TEST(RobotJson, UnknownKeysAreReportedWithTheirPointer) {
  Json json = DefaultRobotJson();
  json["base"]["tick_per_m"] = 11375;
  json["sensor_types"]["short"]["calibraton"] = Json::array();
  json["scanner"]["sensors"][2]["angle"] = 180;
  json["colour"] = "red";
  const Result<RobotDescription> robot = RobotFromJson(json);
  ASSERT_FALSE(robot.ok());
  EXPECT_EQ(Pointers(robot.errors()),
            (std::vector<std::string>{"/base/tick_per_m", "/scanner/sensors/2/angle",
                                      "/sensor_types/short/calibraton", "/colour"}));
  EXPECT_EQ(DetailAt(robot.errors(), "/colour"), "unknown key");
}

TEST(RobotJson, WrongTypesAreReportedWithTheirPointer) {
  const Result<RobotDescription> text_node = RobotWith("/scanner/node", "two");
  ASSERT_FALSE(text_node.ok());
  EXPECT_EQ(Pointers(text_node.errors()), std::vector<std::string>{"/scanner/node"});
  EXPECT_NE(DetailAt(text_node.errors(), "/scanner/node").find("string"), std::string::npos);

  const Result<RobotDescription> fraction = RobotWith("/base/node", 1.5);
  ASSERT_FALSE(fraction.ok());
  EXPECT_EQ(Pointers(fraction.errors()), std::vector<std::string>{"/base/node"});

  EXPECT_TRUE(RobotWith("/base/node", 1.0).ok()) << "an integral number is an integer";
  EXPECT_TRUE(HasPointer(RobotWith("/base/node", 1e12).errors(), "/base/node"));
  EXPECT_TRUE(HasPointer(RobotWith("/base/track_width_m", true).errors(), "/base/track_width_m"));
  EXPECT_TRUE(HasPointer(RobotWith("/base", Json::array()).errors(), "/base"));
  EXPECT_TRUE(HasPointer(RobotWith("/name", 7).errors(), "/name"));
  EXPECT_TRUE(
      HasPointer(RobotWith("/scanner/sensors", Json::object()).errors(), "/scanner/sensors"));
  EXPECT_TRUE(HasPointer(RobotWith("/scanner/sensors/1", 90).errors(), "/scanner/sensors/1"));
  EXPECT_TRUE(HasPointer(RobotWith("/sensor_types/long/range_m", Json::array({0.2})).errors(),
                         "/sensor_types/long/range_m"));
  EXPECT_TRUE(HasPointer(RobotWith("/sensor_types/long/use_m/1", "far").errors(),
                         "/sensor_types/long/use_m/1"));
  EXPECT_TRUE(HasPointer(RobotWith("/sensor_types/short/calibration/5", 603).errors(),
                         "/sensor_types/short/calibration/5"));
  EXPECT_TRUE(HasPointer(RobotWith("/sensor_types/short/calibration/5/0", 602.5).errors(),
                         "/sensor_types/short/calibration/5/0"));
  EXPECT_TRUE(HasPointer(RobotWith("/sensor_types/short/sigma_m", Json::array({0.1, 0.2})).errors(),
                         "/sensor_types/short/sigma_m"));
  EXPECT_FALSE(RobotFromJson(Json::array()).ok());
}

TEST(RobotJson, MissingKeysAreReported) {
  const Result<RobotDescription> robot = RobotWithout("/base/track_width_m");
  ASSERT_FALSE(robot.ok());
  EXPECT_EQ(Pointers(robot.errors()), std::vector<std::string>{"/base/track_width_m"});
  EXPECT_EQ(DetailAt(robot.errors(), "/base/track_width_m"), "missing required key");
  EXPECT_TRUE(HasPointer(RobotWithout("/sensor_types/long/calibration").errors(),
                         "/sensor_types/long/calibration"));
  EXPECT_TRUE(
      HasPointer(RobotWithout("/scanner/sensors/0/type").errors(), "/scanner/sensors/0/type"));
  EXPECT_TRUE(HasPointer(RobotWithout("/name").errors(), "/name"));
}

TEST(RobotJson, OutOfRangeValuesAreReported) {
  EXPECT_EQ(Pointers(RobotWith("/base/node", 256).errors()),
            std::vector<std::string>{"/base/node"});
  EXPECT_TRUE(RobotWith("/base/node", 255).ok());
  EXPECT_TRUE(HasPointer(RobotWith("/scanner/event", 0x8000).errors(), "/scanner/event"));
  EXPECT_TRUE(HasPointer(RobotWith("/base/ticks_per_m", 0).errors(), "/base/ticks_per_m"));
  EXPECT_TRUE(HasPointer(RobotWith("/base/gyro_unit_dps", -0.01).errors(), "/base/gyro_unit_dps"));
  EXPECT_TRUE(
      HasPointer(RobotWith("/scanner/sample_rate_hz", 0).errors(), "/scanner/sample_rate_hz"));
  EXPECT_TRUE(
      HasPointer(RobotWith("/scanner/mount_radius_m", -0.01).errors(), "/scanner/mount_radius_m"));
  EXPECT_TRUE(RobotWith("/scanner/mount_radius_m", 0).ok());
  EXPECT_TRUE(HasPointer(RobotWith("/scanner/sensors/2/type", "medium").errors(),
                         "/scanner/sensors/2/type"));
  EXPECT_TRUE(HasPointer(RobotWith("/sensor_types/long/range_m", Json::array({1.5, 0.2})).errors(),
                         "/sensor_types/long/range_m"));
  EXPECT_TRUE(HasPointer(RobotWith("/sensor_types/long/use_m", Json::array({1.0, 1.0})).errors(),
                         "/sensor_types/long/use_m"));
  EXPECT_TRUE(HasPointer(RobotWith("/sensor_types/long/sigma_m/2", -0.1).errors(),
                         "/sensor_types/long/sigma_m/2"));
  EXPECT_TRUE(HasPointer(RobotWith("/sensor_types/short/sigma_m/0", 0.0).errors(),
                         "/sensor_types/short/sigma_m"))
      << "short's use window starts at 0 m, where sigma would be 0";
  EXPECT_TRUE(RobotWith("/sensor_types/long/sigma_m/0", 0.0).ok())
      << "long's use window starts at 0.35 m, where sigma is still > 0";
  EXPECT_TRUE(HasPointer(RobotWith("/sensor_types/short/calibration/0/0", 1024).errors(),
                         "/sensor_types/short/calibration/0"));

  // 1 to 4 sensors (a laser is one); none, or more than the scanner event carries, is an error.
  Json three_sensors = DefaultRobotJson();
  three_sensors["scanner"]["sensors"].erase(3);
  EXPECT_TRUE(RobotFromJson(three_sensors).ok());
  Json no_sensor = DefaultRobotJson();
  no_sensor["scanner"]["sensors"] = Json::array();
  EXPECT_EQ(Pointers(RobotFromJson(no_sensor).errors()),
            std::vector<std::string>{"/scanner/sensors"});
  Json five_sensors = DefaultRobotJson();
  five_sensors["scanner"]["sensors"].push_back(five_sensors["scanner"]["sensors"][0]);
  EXPECT_EQ(Pointers(RobotFromJson(five_sensors).errors()),
            std::vector<std::string>{"/scanner/sensors"});
}

TEST(RobotJson, ImplausiblyLargeValuesAreReportedNamingTheKey) {
  // Finite but absurd values used to be accepted, and a calibration distance of 1e6 m made the
  // sensor model's tables allocate gigabytes at start.
  const auto message_at = [](const Result<RobotDescription>& robot, const std::string& pointer) {
    for (const ConfigError& e : robot.errors()) {
      if (e.pointer == pointer) return e.detail;
    }
    return std::string("(no error at " + pointer + ")");
  };
  const auto calibration = RobotWith("/sensor_types/long/calibration/14/1", 1e6);
  EXPECT_EQ(message_at(calibration, "/sensor_types/long/calibration/14/1"),
            "1e+06 m is beyond any plausible value (at most 100 m)");
  EXPECT_TRUE(HasPointer(RobotWith("/sensor_types/long/range_m", Json::array({0.2, 1e6})).errors(),
                         "/sensor_types/long/range_m/1"));
  EXPECT_TRUE(HasPointer(RobotWith("/sensor_types/long/use_m", Json::array({0.3, 500})).errors(),
                         "/sensor_types/long/use_m/1"));
  EXPECT_EQ(
      message_at(RobotWith("/sensor_types/long/sigma_m/2", 1e4), "/sensor_types/long/sigma_m"),
      "sigma(1 m) = 10000 m is beyond any plausible noise (at most 10 m over the use window)");
  EXPECT_TRUE(HasPointer(RobotWith("/base/track_width_m", 1e9).errors(), "/base/track_width_m"));
  EXPECT_TRUE(HasPointer(RobotWith("/base/ticks_per_m", 1e-6).errors(), "/base/ticks_per_m"));
  EXPECT_TRUE(HasPointer(RobotWith("/base/ticks_per_m", 1e12).errors(), "/base/ticks_per_m"));
  EXPECT_TRUE(HasPointer(RobotWith("/base/gyro_unit_dps", 1e5).errors(), "/base/gyro_unit_dps"));
  EXPECT_TRUE(
      HasPointer(RobotWith("/scanner/sample_rate_hz", 1e7).errors(), "/scanner/sample_rate_hz"));
  EXPECT_TRUE(
      HasPointer(RobotWith("/scanner/mount_radius_m", 50).errors(), "/scanner/mount_radius_m"));
  EXPECT_EQ(
      message_at(RobotWith("/scanner/sensors/1/angle_deg", 1e300), "/scanner/sensors/1/angle_deg"),
      "1e+300 deg is outside the plausible [-360, 360] deg");
  // The bounds themselves are accepted.
  EXPECT_TRUE(RobotWith("/scanner/sensors/1/angle_deg", -360).ok());
  EXPECT_TRUE(RobotWith("/base/track_width_m", 10).ok());
}

TEST(RobotJson, NonMonotonicCalibrationIsReported) {
  // Point 3 reads more than point 2: raw must strictly decrease as distance grows.
  const Result<RobotDescription> raw = RobotWith("/sensor_types/long/calibration/3/0", 700);
  ASSERT_FALSE(raw.ok());
  EXPECT_EQ(Pointers(raw.errors()), std::vector<std::string>{"/sensor_types/long/calibration/3"});
  EXPECT_NE(DetailAt(raw.errors(), "/sensor_types/long/calibration/3").find("decreasing"),
            std::string::npos);

  const Result<RobotDescription> distance = RobotWith("/sensor_types/long/calibration/3/1", 0.2);
  ASSERT_FALSE(distance.ok());
  EXPECT_EQ(Pointers(distance.errors()),
            std::vector<std::string>{"/sensor_types/long/calibration/3"});

  EXPECT_TRUE(HasPointer(RobotWith("/sensor_types/short/calibration/0/1", -0.04).errors(),
                         "/sensor_types/short/calibration/0"));
  EXPECT_TRUE(HasPointer(
      RobotWith("/sensor_types/short/calibration", Json::array({Json::array({822, 0.04})}))
          .errors(),
      "/sensor_types/short/calibration"));
}

TEST(RobotJson, DuplicateKeysInTextAreReported) {
  TempDir dir("duplicate");
  const std::string path = dir.File("dup.robot.json");
  std::string text = DefaultRobotJson().dump();
  const std::string key = "\"gyro_unit_dps\":0.01";
  const std::size_t at = text.find(key);
  ASSERT_NE(at, std::string::npos);
  text.insert(at, "\"gyro_unit_dps\":0.02,");
  WriteText(path, text);
  const Result<RobotDescription> robot = LoadRobot(path);
  ASSERT_FALSE(robot.ok());
  EXPECT_EQ(Pointers(robot.errors()), std::vector<std::string>{"/base/gyro_unit_dps"});
  EXPECT_EQ(DetailAt(robot.errors(), "/base/gyro_unit_dps"), "duplicate key");
}

TEST(RobotJson, SensorTypeNamesAreEscapedInPointers) {
  Json json = DefaultRobotJson();
  json["sensor_types"]["a/b"] = json["sensor_types"]["long"];
  json["sensor_types"]["a/b"]["range_m"] = Json::array({0.5, 0.1});
  json["sensor_types"]["a/b"]["extra"] = 1;
  const Result<RobotDescription> robot = RobotFromJson(json);
  ASSERT_FALSE(robot.ok());
  EXPECT_EQ(Pointers(robot.errors()), std::vector<std::string>{"/sensor_types/a~1b/extra"});
  json["sensor_types"]["a/b"].erase("extra");
  EXPECT_EQ(Pointers(RobotFromJson(json).errors()),
            std::vector<std::string>{"/sensor_types/a~1b/range_m"});
}

TEST(RobotJson, MissingFileNamesThePath) {
  const std::string path = (kSourceDir / "config" / "no_such_file.robot.json").string();
  const Result<RobotDescription> robot = LoadRobot(path);
  ASSERT_FALSE(robot.ok());
  EXPECT_EQ(robot.error_context(), path);
  EXPECT_NE(robot.Message().find(path), std::string::npos) << robot.Message();
  EXPECT_NE(robot.Message().find("cannot open"), std::string::npos) << robot.Message();
}

TEST(RobotJson, MalformedJsonNamesThePathAndLine) {
  TempDir dir("malformed");
  const std::string path = dir.File("broken.robot.json");
  WriteText(path, "{\n  \"name\": \"marxbot\",\n  \"base\": {\"node\": 1,}\n}\n");
  const Result<RobotDescription> robot = LoadRobot(path);
  ASSERT_FALSE(robot.ok());
  const std::string message = robot.Message();
  EXPECT_NE(message.find(path), std::string::npos) << message;
  EXPECT_NE(message.find("line 3"), std::string::npos) << message;
  EXPECT_EQ(message.find("[json.exception"), std::string::npos) << message;

  WriteText(path, "");
  EXPECT_NE(LoadRobot(path).Message().find("line"), std::string::npos);
  EXPECT_FALSE(LoadRobot(dir.path().string()).ok()) << "a directory is not a file";
}

TEST(RobotJson, ValidationErrorsOfAFileCarryItsPath) {
  TempDir dir("invalid");
  const std::string path = dir.File("bad.robot.json");
  Json json = DefaultRobotJson();
  json["base"]["node"] = 300;
  WriteText(path, json.dump(2));
  const Result<RobotDescription> robot = LoadRobot(path);
  ASSERT_FALSE(robot.ok());
  EXPECT_EQ(Pointers(robot.errors()), std::vector<std::string>{"/base/node"});
  // dump(2) sorts the keys: "{", "base": {, "event", "gyro_unit_dps", then "node" on line 5.
  EXPECT_EQ(robot.Message(), path + ":5: /base/node: 300 is outside [0, 255]");
}

// --- Validate(RobotDescription) on structs (values JSON cannot carry) ---------------------------

TEST(RobotValidate, RejectsNonFiniteValues) {
  RobotDescription robot = LoadRobot(kDefaultRobot).value();
  ASSERT_TRUE(Validate(robot).empty());
  robot.base.track_width_m = std::numeric_limits<double>::quiet_NaN();
  robot.scanner.sensors[1].angle_deg = std::numeric_limits<double>::infinity();
  robot.sensor_types.at("long").range_max_m = std::numeric_limits<double>::infinity();
  EXPECT_EQ(Pointers(Validate(robot)),
            (std::vector<std::string>{"/base/track_width_m", "/scanner/sensors/1/angle_deg",
                                      "/sensor_types/long/range_m"}));
}

TEST(RobotValidate, RejectsSameEventFromBaseAndScanner) {
  RobotDescription robot = LoadRobot(kDefaultRobot).value();
  robot.scanner.node = robot.base.node;
  EXPECT_TRUE(Validate(robot).empty()) << "same node, different events is fine";
  robot.scanner.event = robot.base.event;
  EXPECT_EQ(Pointers(Validate(robot)), std::vector<std::string>{"/scanner/event"});
}

TEST(RobotValidate, EmptyDescriptionIsInvalid) {
  const ConfigErrors errors = Validate(RobotDescription{});
  EXPECT_TRUE(HasPointer(errors, "/scanner/sensors"));
}

// --- Params ------------------------------------------------------------------------------------

SlamParams TunedParams() {
  SlamParams params;
  params.dist_error_ratio = 0.0731;
  params.dist_error_const_m = 0.1 + 0.2;  // a double whose shortest text is long
  params.angle_error_ratio = 0.0;
  params.angle_error_const_deg = 1.0 / 3.0;
  params.min_pos_uncertainty_m = 0.5;
  params.min_angle_uncertainty_deg = 7.25;
  params.resampling_period_scans = 3;
  params.angle_between_scans_deg = 12.5;
  params.particles = 40;
  return params;
}

TEST(ParamsJson, RoundTripIsExact) {
  const SlamParams params = TunedParams();
  ASSERT_NE(params, SlamParams{});
  const Result<SlamParams> again = ParamsFromJson(Json::parse(ParamsToJson(params).dump()));
  ASSERT_TRUE(again.ok()) << again.Message();
  EXPECT_EQ(again.value(), params);
}

TEST(ParamsJson, AllKeysAreOptional) {
  const Result<SlamParams> empty = ParamsFromJson(Json::object());
  ASSERT_TRUE(empty.ok()) << empty.Message();
  EXPECT_EQ(empty.value(), SlamParams{});

  const Result<SlamParams> one = ParamsFromJson({{"particles", 5}});
  ASSERT_TRUE(one.ok()) << one.Message();
  SlamParams expected;
  expected.particles = 5;
  EXPECT_EQ(one.value(), expected);
}

TEST(ParamsJson, IntegersMustBeIntegral) {
  const Result<SlamParams> whole = ParamsFromJson({{"particles", 4.0}});
  ASSERT_TRUE(whole.ok()) << whole.Message();
  EXPECT_EQ(whole.value().particles, 4);

  const Result<SlamParams> fraction = ParamsFromJson({{"resampling_period_scans", 2.5}});
  ASSERT_FALSE(fraction.ok());
  EXPECT_EQ(Pointers(fraction.errors()), std::vector<std::string>{"/resampling_period_scans"});
}

TEST(ParamsJson, UnknownKeysAndWrongTypesAreReported) {
  const Result<SlamParams> typo = ParamsFromJson({{"partciles", 4}, {"particles", 2}});
  ASSERT_FALSE(typo.ok());
  EXPECT_EQ(Pointers(typo.errors()), std::vector<std::string>{"/partciles"});
  EXPECT_EQ(DetailAt(typo.errors(), "/partciles"), "unknown key");

  const Result<SlamParams> text =
      ParamsFromJson({{"particles", "4"}, {"dist_error_ratio", nullptr}});
  ASSERT_FALSE(text.ok());
  EXPECT_EQ(Pointers(text.errors()), (std::vector<std::string>{"/dist_error_ratio", "/particles"}));

  const Result<SlamParams> not_object = ParamsFromJson(Json::array({1, 2}));
  ASSERT_FALSE(not_object.ok());
  EXPECT_EQ(Pointers(not_object.errors()), std::vector<std::string>{""});
}

TEST(ParamsJson, OutOfRangeValuesAreReported) {
  const Result<SlamParams> params = ParamsFromJson(
      {{"particles", 0}, {"dist_error_ratio", 1.5}, {"angle_between_scans_deg", 180}});
  ASSERT_FALSE(params.ok());
  EXPECT_EQ(Pointers(params.errors()),
            (std::vector<std::string>{"/dist_error_ratio", "/particles"}));
  EXPECT_EQ(DetailAt(params.errors(), "/particles"), "0 is outside [1, 1000]");
  EXPECT_FALSE(ParamsFromJson({{"particles", 1001}}).ok());
  EXPECT_TRUE(ParamsFromJson({{"particles", 1000}}).ok());
  EXPECT_FALSE(ParamsFromJson({{"resampling_period_scans", 0}}).ok());
  EXPECT_FALSE(ParamsFromJson({{"min_angle_uncertainty_deg", 90.5}}).ok());
  EXPECT_FALSE(ParamsFromJson({{"dist_error_const_m", -0.001}}).ok());
  EXPECT_FALSE(ParamsFromJson({{"particles", 1e10}}).ok()) << "does not fit an int";
}

TEST(ParamsValidate, RejectsNonFiniteValues) {
  SlamParams params;
  params.min_pos_uncertainty_m = std::numeric_limits<double>::quiet_NaN();
  params.angle_error_ratio = std::numeric_limits<double>::infinity();
  EXPECT_EQ(Pointers(Validate(params)),
            (std::vector<std::string>{"/angle_error_ratio", "/min_pos_uncertainty_m"}));
  EXPECT_TRUE(Validate(SlamParams{}).empty());
}

TEST(ParamsJson, SaveThenLoadRoundTripsAtomically) {
  TempDir dir("save");
  const std::string path = dir.File("params.json");
  const SlamParams params = TunedParams();
  ASSERT_TRUE(SaveParams(path, SlamParams{}).ok());
  ASSERT_TRUE(SaveParams(path, params).ok());  // replaces the existing file
  const Result<SlamParams> loaded = LoadParams(path);
  ASSERT_TRUE(loaded.ok()) << loaded.Message();
  EXPECT_EQ(loaded.value(), params);
  // No temporary file is left behind.
  std::vector<std::string> names;
  for (const fs::directory_entry& entry : fs::directory_iterator(dir.path())) {
    names.push_back(entry.path().filename().string());
  }
  EXPECT_EQ(names, std::vector<std::string>{"params.json"});
}

TEST(ParamsJson, SaveRefusesInvalidParamsAndBadPaths) {
  TempDir dir("save_errors");
  const std::string path = dir.File("params.json");
  SlamParams invalid;
  invalid.particles = 0;
  const Result<void> refused = SaveParams(path, invalid);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.Message().find("/particles"), std::string::npos) << refused.Message();
  EXPECT_FALSE(fs::exists(path));

  const Result<void> no_dir = SaveParams(dir.File("missing/params.json"), {});
  ASSERT_FALSE(no_dir.ok());
  EXPECT_NE(no_dir.Message().find("missing"), std::string::npos) << no_dir.Message();
}

TEST(ParamsJson, LoadErrorsNameThePath) {
  TempDir dir("load_errors");
  const std::string missing = dir.File("params.absent.json");
  EXPECT_NE(LoadParams(missing).Message().find(missing), std::string::npos);

  const std::string broken = dir.File("params.broken.json");
  WriteText(broken, "{\"particles\": 1\n\"x\": 2}");
  const Result<SlamParams> params = LoadParams(broken);
  ASSERT_FALSE(params.ok());
  EXPECT_NE(params.Message().find(broken), std::string::npos) << params.Message();
  EXPECT_NE(params.Message().find("line 2"), std::string::npos) << params.Message();
}

TEST(ParamsPatch, AppliesAMergePatch) {
  const SlamParams base = TunedParams();
  const Result<SlamParams> patched =
      ApplyParamsPatch(base, {{"particles", 8}, {"min_pos_uncertainty_m", 0.03}});
  ASSERT_TRUE(patched.ok()) << patched.Message();
  SlamParams expected = base;
  expected.particles = 8;
  expected.min_pos_uncertainty_m = 0.03;
  EXPECT_EQ(patched.value(), expected);

  // RFC 7396: null removes the member, which brings back the default.
  const Result<SlamParams> reset = ApplyParamsPatch(base, {{"particles", nullptr}});
  ASSERT_TRUE(reset.ok()) << reset.Message();
  EXPECT_EQ(reset.value().particles, SlamParams{}.particles);
  EXPECT_EQ(reset.value().resampling_period_scans, base.resampling_period_scans);

  const Result<SlamParams> empty = ApplyParamsPatch(base, Json::object());
  ASSERT_TRUE(empty.ok());
  EXPECT_EQ(empty.value(), base);
}

TEST(ParamsPatch, RejectsInvalidResults) {
  const SlamParams base = TunedParams();
  EXPECT_EQ(Pointers(ApplyParamsPatch(base, {{"particles", 0}}).errors()),
            std::vector<std::string>{"/particles"});
  EXPECT_EQ(Pointers(ApplyParamsPatch(base, {{"particls", 3}}).errors()),
            std::vector<std::string>{"/particls"});
  EXPECT_EQ(Pointers(ApplyParamsPatch(base, {{"particles", {{"n", 3}}}}).errors()),
            std::vector<std::string>{"/particles"});
  EXPECT_EQ(Pointers(ApplyParamsPatch(base, Json::array({1})).errors()),
            std::vector<std::string>{""});
  // Type errors and range errors come back together, so one answer lists every problem.
  EXPECT_EQ(
      Pointers(ApplyParamsPatch(base, {{"particles", 2.5}, {"dist_error_ratio", 3}}).errors()),
      (std::vector<std::string>{"/particles", "/dist_error_ratio"}));
}

TEST(ConfigErrors, FormatOneLinePerError) {
  EXPECT_EQ(FormatErrors({}), "");
  EXPECT_EQ(FormatErrors({{"/particles", "0 is outside [1, 1000]"}, {"", "file.json: bad"}}),
            "/particles: 0 is outside [1, 1000]\nfile.json: bad");
}

// ---------------------------------------------------------------------------------------------
// map_server maps.

constexpr int kLimit = 5000;  // the engine's clamp (5 in natural log odds)

/// A map over four tiles around the origin (negative cells too): walls, free space, cells of
/// every log odds the export classifies, and unknown holes.
OccupancyGrid DrawnMap(double resolution) {
  OccupancyGrid grid(GridGeometry(resolution), kLimit);
  grid.BeginWrite();
  for (int j = -40; j < 50; ++j) {
    for (int i = -70; i < 30; ++i) {
      if ((i * 7 + j * 3) % 11 == 0) continue;  // unknown holes
      const bool wall = i == -70 || j == -40 || i == 29 || j == 49 || (i == 0 && j > 10);
      const int value = wall                ? kLimit
                        : (i + j) % 13 == 0 ? 400
                        : (i - j) % 17 == 0 ? -900
                                            : -kLimit;
      grid.Add({i, j}, value);
    }
  }
  grid.RefreshSummaries();
  return grid;
}

/// -1 free, 1 occupied, 0 unknown: the export's classification of a cell (MakeGridImage).
int Classify(LogOdds v) {
  const double p = OccupancyProbability(v);
  return p >= kOccupiedThreshold ? 1 : p <= kFreeThreshold ? -1 : 0;
}

/// The same of a cell read back: it must be exactly the clamp, its negative or 0.
int ClassifyLoaded(LogOdds v) {
  EXPECT_TRUE(v == kLimit || v == -kLimit || v == 0) << v;
  return v == kLimit ? 1 : v == -kLimit ? -1 : 0;
}

void WriteBytes(const std::string& path, const std::string& text) {
  std::ofstream(path, std::ios::binary | std::ios::trunc) << text;
}

/// map.yaml text as map_server's keys, with `image` and overrides of single lines.
std::string YamlText(const std::string& image, const std::string& extra = "") {
  return "image: " + image +
         "\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: 0\noccupied_thresh: 0.65\n"
         "free_thresh: 0.196\n" +
         extra;
}

TEST(MapYaml, TheProjectsExportReadsBackCellForCellAsPgmAndAsPng) {
  const testing::TempDir dir("map_yaml_round_trip");
  const OccupancyGrid grid = DrawnMap(0.01);
  const GridImage image = MakeGridImage(grid);
  ASSERT_EQ(image.cells_per_pixel, 1);
  ASSERT_TRUE(WritePgm(dir.File("map.pgm"), image).ok());
  ASSERT_TRUE(WriteMapYaml(dir.File("map.yaml"), "map.pgm", image).ok());
  const Result<PngBytes> png = EncodeGrayPng(image.width, image.height, image.gray);
  ASSERT_TRUE(png.ok());
  WriteBytes(dir.File("map.png"), std::string(png.value().begin(), png.value().end()));
  WriteBytes(dir.File("png.yaml"), MapYaml("map.png", image));
  for (const char* yaml : {"map.yaml", "png.yaml"}) {
    const Result<OccupancyGrid> loaded = LoadMapYaml(dir.File(yaml), GridGeometry(0.01), kLimit);
    ASSERT_TRUE(loaded.ok()) << loaded.Message();
    int known = 0;
    for (int j = -80; j < 100; ++j) {
      for (int i = -100; i < 80; ++i) {
        const int expected = Classify(grid.At({i, j}));
        ASSERT_EQ(ClassifyLoaded(loaded.value().At({i, j})), expected)
            << yaml << " " << i << "," << j;
        known += expected != 0 ? 1 : 0;
      }
    }
    EXPECT_GT(known, 6000);
    EXPECT_EQ(loaded.value().limit(), kLimit);
  }
}

TEST(MapYaml, AnotherResolutionTakesThePixelUnderEachCellsCentre) {
  const testing::TempDir dir("map_yaml_resample");
  const OccupancyGrid grid = DrawnMap(0.01);
  const GridImage image = MakeGridImage(grid);
  ASSERT_TRUE(WritePgm(dir.File("map.pgm"), image).ok());
  ASSERT_TRUE(WriteMapYaml(dir.File("map.yaml"), "map.pgm", image).ok());
  for (const double resolution : {0.03, 0.005, 0.013}) {
    const GridGeometry geometry(resolution);
    const Result<OccupancyGrid> loaded = LoadMapYaml(dir.File("map.yaml"), geometry, kLimit);
    ASSERT_TRUE(loaded.ok()) << loaded.Message();
    const int n = static_cast<int>(1.0 / resolution);
    for (int j = -n; j < n; ++j) {
      for (int i = -n; i < n; ++i) {
        const CellIndex under = grid.geometry().CellOf(geometry.CellCenter({i, j}));
        ASSERT_EQ(ClassifyLoaded(loaded.value().At({i, j})), Classify(grid.At(under)))
            << resolution << ": " << i << "," << j;
      }
    }
  }
}

TEST(MapYaml, AnExportCoarserThanTheMapGivesEachCellItsPixel) {
  const testing::TempDir dir("map_yaml_coarse");
  const OccupancyGrid grid = DrawnMap(0.01);
  const GridImage image = MakeGridImage(grid, 4000);  // 3 cells a pixel side
  ASSERT_EQ(image.cells_per_pixel, 3);
  ASSERT_TRUE(WritePgm(dir.File("map.pgm"), image).ok());
  ASSERT_TRUE(WriteMapYaml(dir.File("map.yaml"), "map.pgm", image).ok());
  const Result<OccupancyGrid> loaded =
      LoadMapYaml(dir.File("map.yaml"), GridGeometry(0.01), kLimit);
  ASSERT_TRUE(loaded.ok()) << loaded.Message();
  for (int j = -40; j < 50; ++j) {
    for (int i = -70; i < 30; ++i) {
      // The pixel's cells: occupied if any is, else free if any is (MakeGridImage).
      const int x0 = -128 + ((i + 128) / 3) * 3, y0 = -64 + ((j + 64) / 3) * 3;
      int expected = 0;
      for (int y = y0; y < y0 + 3; ++y) {
        for (int x = x0; x < x0 + 3; ++x) {
          const int c = Classify(grid.At({x, y}));
          expected = c == 1 || expected == 1 ? 1 : std::min(expected, c);
        }
      }
      ASSERT_EQ(ClassifyLoaded(loaded.value().At({i, j})), expected) << i << "," << j;
    }
  }
}

TEST(MapYaml, NegateScaleModeAndARotatedOrigin) {
  const testing::TempDir dir("map_yaml_modes");
  // 3 x 2 pixels, top row first: occupied, free, unknown / free, grey 128, occupied.
  const std::string pixels = {'\0', '\xfe', '\xcd', '\xfe', '\x80', '\0'};
  WriteBytes(dir.File("m.pgm"), "P5\n# a comment\n3 2\n255\n" + pixels);
  std::string negated;
  for (const char c : pixels) negated.push_back(static_cast<char>(255 - static_cast<uint8_t>(c)));
  WriteBytes(dir.File("n.pgm"), "P5 3 2 255\n" + negated);
  const auto load = [&](const std::string& yaml, double resolution = 1.0) {
    WriteBytes(dir.File("m.yaml"), yaml);
    return LoadMapYaml(dir.File("m.yaml"), GridGeometry(resolution), kLimit);
  };
  const std::string base =
      "resolution: 1.0\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n";
  const auto plain = load("image: m.pgm\norigin: [0, 0, 0]\n" + base);
  ASSERT_TRUE(plain.ok()) << plain.Message();
  const auto expect_cells = [](const OccupancyGrid& g, const std::vector<CellIndex>& cells,
                               const std::vector<int>& classes) {
    for (size_t k = 0; k < cells.size(); ++k) {
      EXPECT_EQ(ClassifyLoaded(g.At(cells[k])), classes[k]) << cells[k].x << "," << cells[k].y;
    }
  };
  // Row 0 of the image is the top: y = 1.
  const std::vector<CellIndex> cells{{0, 1}, {1, 1}, {2, 1}, {0, 0}, {1, 0}, {2, 0}};
  expect_cells(plain.value(), cells, {1, -1, 0, -1, 0, 1});
  EXPECT_EQ(plain.value().At({1, 0}), 0);  // grey 128: p = 0.498, unknown in trinary mode
  // negate: 1 on the inverted image reads the same.
  const std::string negate_base =
      "resolution: 1.0\nnegate: 1\noccupied_thresh: 0.65\nfree_thresh: 0.196\n";
  const auto negate = load("image: n.pgm\norigin: [0, 0, 0]\n" + negate_base);
  ASSERT_TRUE(negate.ok()) << negate.Message();
  expect_cells(negate.value(), cells, {1, -1, 0, -1, 0, 1});
  // Scale: the grey pixel holds the log odds of its occupancy, 127 / 255.
  const auto scale = load("image: m.pgm\norigin: [0, 0, 0]\nmode: scale\n" + base);
  ASSERT_TRUE(scale.ok()) << scale.Message();
  EXPECT_EQ(scale.value().At({1, 0}), EncodeLogOdds(std::log(127.0 / 128.0)));
  // Raw: the values are percentages; 0 free, the rest above 100 unknown.
  const auto raw = load("image: m.pgm\norigin: [0, 0, 0]\nmode: raw\n" + base);
  ASSERT_TRUE(raw.ok()) << raw.Message();
  expect_cells(raw.value(), cells, {-1, 0, 0, 0, 0, -1});
  // The origin at (10, 5) turned by 90 degrees: image x runs along world y, image y along -x.
  const auto turned = load("image: m.pgm\norigin: [10.0, 5.0, 1.5707963267948966]\n" + base);
  ASSERT_TRUE(turned.ok()) << turned.Message();
  // Pixel (column u, row v from the bottom) covers world x in [10 - v - 1, 10 - v], y in
  // [5 + u, 5 + u + 1].
  expect_cells(turned.value(), {{8, 5}, {8, 6}, {8, 7}, {9, 5}, {9, 6}, {9, 7}},
               {1, -1, 0, -1, 0, 1});
  EXPECT_EQ(turned.value().At({10, 5}), 0);
  EXPECT_EQ(turned.value().At({7, 5}), 0);
}

TEST(MapYaml, EveryBadKeyIsAnErrorWithItsFileAndLine) {
  const std::string path = "dir/map.yaml";
  struct Case {
    std::string yaml;
    std::string message;  // a part of the error's text
  };
  const std::vector<Case> cases = {
      {"resolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.2\n",
       "dir/map.yaml: missing key 'image'"},
      {YamlText("m.pgm").substr(0, YamlText("m.pgm").find("free_thresh")),
       "dir/map.yaml: missing key 'free_thresh'"},
      {"image: m.pgm\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.2\n",
       "missing key 'resolution'"},
      {"image: m.pgm\nresolution: 0.05\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.2\n",
       "missing key 'origin'"},
      {"image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.65\n"
       "free_thresh: 0.2\n",
       "missing key 'negate'"},
      {"image: m.pgm\nresolution: fine\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\n"
       "free_thresh: 0.2\n",
       "dir/map.yaml:2: resolution: 'fine' is not a finite number"},
      {"image: m.pgm\nresolution: nan\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\n"
       "free_thresh: 0.2\n",
       "dir/map.yaml:2: resolution: 'nan' is not a finite number"},
      {"image: m.pgm\nresolution: .inf\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\n"
       "free_thresh: 0.2\n",
       "dir/map.yaml:2: resolution: '.inf' is not a finite number"},
      {"image: m.pgm\nresolution: 1e999\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\n"
       "free_thresh: 0.2\n",
       "dir/map.yaml:2: resolution"},
      {"image: m.pgm\nresolution: \"0.05\"\norigin: [0, 0, 0]\nnegate: 0\n"
       "occupied_thresh: 0.65\nfree_thresh: 0.2\n",
       "dir/map.yaml:2: resolution: '0.05' is not a finite number"},
      {"image: m.pgm\nresolution: -0.05\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\n"
       "free_thresh: 0.2\n",
       "dir/map.yaml:2: resolution: must be above 0"},
      {"image: m.pgm\nresolution: 0\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\n"
       "free_thresh: 0.2\n",
       "dir/map.yaml:2: resolution: must be above 0"},
      {YamlText("m.pgm").replace(YamlText("m.pgm").find("[0.0, 0.0, 0.0]"), 15, "[1, 2]"),
       "dir/map.yaml:3: origin: '[1, 2]' is not [x, y, yaw]"},
      {YamlText("m.pgm").replace(YamlText("m.pgm").find("[0.0, 0.0, 0.0]"), 15, "[1, 2, 3, 4]"),
       "dir/map.yaml:3: origin"},
      {YamlText("m.pgm").replace(YamlText("m.pgm").find("[0.0, 0.0, 0.0]"), 15, "[1, nan, 0]"),
       "dir/map.yaml:3: origin"},
      {YamlText("m.pgm").replace(YamlText("m.pgm").find("[0.0, 0.0, 0.0]"), 15, "5"),
       "dir/map.yaml:3: origin"},
      {YamlText("m.pgm").replace(YamlText("m.pgm").find("[0.0, 0.0, 0.0]"), 15, "[1, 2,"),
       "dir/map.yaml:3: origin"},
      {YamlText("m.pgm").replace(YamlText("m.pgm").find("negate: 0"), 9, "negate: 2"),
       "dir/map.yaml:4: negate: '2' is not 0 or 1"},
      {YamlText("m.pgm").replace(YamlText("m.pgm").find("0.65"), 4, "1.5"),
       "dir/map.yaml:5: occupied_thresh: must be within 0 to 1"},
      {YamlText("m.pgm").replace(YamlText("m.pgm").find("0.65"), 4, "high"),
       "dir/map.yaml:5: occupied_thresh: 'high' is not a finite number"},
      {YamlText("m.pgm").replace(YamlText("m.pgm").find("0.196"), 5, "0.7"),
       "dir/map.yaml:6: free_thresh: must be below occupied_thresh"},
      {YamlText("m.pgm", "mode: fancy\n"), "dir/map.yaml:7: mode: 'fancy' is not trinary"},
      {YamlText("m.pgm", "resolution: 0.1\n"),
       "dir/map.yaml:7: resolution: given twice (first on line 2)"},
      {YamlText("m.pgm", "  nested: 1\n"), "dir/map.yaml:7: an indented line"},
      {YamlText("m.pgm", "just words\n"), "dir/map.yaml:7: expected \"key: value\""},
      {YamlText("m.pgm", "extra:\n"), "dir/map.yaml:7: extra: no value"},
      {YamlText("\"m.pgm"), "dir/map.yaml:1: image: a quoted value that does not end"},
      {"", "missing key 'image'"},
  };
  for (const Case& c : cases) {
    const Result<MapYamlKeys> parsed = ParseMapYaml(c.yaml, path);
    ASSERT_FALSE(parsed.ok()) << c.yaml;
    EXPECT_NE(parsed.Message().find(c.message), std::string::npos)
        << "wanted \"" << c.message << "\" in:\n"
        << parsed.Message();
  }
  // What map_server accepts: comments, quotes, a document marker, unknown keys, true/false.
  const Result<MapYamlKeys> good = ParseMapYaml(
      "---\n# a map\nimage: \"my map #1.pgm\"  # the image\nresolution: 0.05\n"
      "origin: [-1.5, 2, 0.25]\nnegate: false\noccupied_thresh: 0.65\n"
      "free_thresh: 0.196\nmode: trinary\nunknown_key: 3\n",
      path);
  ASSERT_TRUE(good.ok()) << good.Message();
  EXPECT_EQ(good.value().image, "my map #1.pgm");
  EXPECT_EQ(good.value().origin.x, -1.5);
  EXPECT_EQ(good.value().origin.y, 2.0);
  EXPECT_EQ(good.value().origin.theta, 0.25);
  EXPECT_FALSE(good.value().negate);
}

TEST(MapYaml, BadImagesAndFilesAreErrorsNamingTheFile) {
  const testing::TempDir dir("map_yaml_bad_images");
  const auto load = [&](const std::string& image_bytes, const std::string& extra = "",
                        double resolution = 0.05) {
    WriteBytes(dir.File("m.img"), image_bytes);
    WriteBytes(dir.File("m.yaml"), YamlText("m.img", extra));
    return LoadMapYaml(dir.File("m.yaml"), GridGeometry(resolution), kLimit);
  };
  const auto expect_error = [&](const Result<OccupancyGrid>& r, const std::string& part) {
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.Message().find(part), std::string::npos) << "wanted \"" << part << "\" in:\n"
                                                         << r.Message();
  };
  const std::string img = dir.File("m.img");
  EXPECT_TRUE(load("P5 2 2 255\n" + std::string(4, '\xfe')).ok());
  expect_error(load(""), img + ": neither a binary PGM (P5) nor a PNG");
  expect_error(load("hello"), img + ": neither a binary PGM (P5) nor a PNG");
  expect_error(load("P2 2 2 255\n1 2 3 4\n"), img + ": a Netpbm image of type P2");
  expect_error(load("P5 2 2 255\n" + std::string(3, '\0')), img + ": truncated: 3 of 4 pixel");
  expect_error(load("P5 2 2"), img + ": a PGM header that does not parse");
  expect_error(load("P5 2 x 255\n"), img + ": a PGM header that does not parse");
  expect_error(load("P5 2 2 65535\n" + std::string(8, '\0')), img + ": PGM maxval 65535");
  expect_error(load("P5 0 2 255\n"), img + ": an image of 0 x 2 pixels");
  expect_error(load("P5 100000 100000 255\n"), "an image of 100000 x 100000 pixels");
  expect_error(load("P5 99999999999 2 255\n"), img + ": a PGM header that does not parse");
  // A PNG cut short, and one damaged.
  const Result<PngBytes> png = EncodeGrayPng(40, 30, std::vector<uint8_t>(1200, 254));
  ASSERT_TRUE(png.ok());
  const std::string png_bytes(png.value().begin(), png.value().end());
  EXPECT_TRUE(load(png_bytes).ok());
  expect_error(load(png_bytes.substr(0, png_bytes.size() / 2)), img + ": not a readable PNG");
  expect_error(load(png_bytes.substr(0, 20)), img + ": not a readable PNG");
  std::string damaged = png_bytes;
  for (size_t i = 40; i < damaged.size() - 20; i += 7) damaged[i] = static_cast<char>(~damaged[i]);
  expect_error(load(damaged), img + ": not a readable PNG");
  // An image reaching beyond the map's bound: 4 x 4 pixels of 300 m at 5 cm cells (+-409.6 m).
  WriteBytes(dir.File("far.yaml"),
             "image: m.img\nresolution: 300\norigin: [0, 0, 0]\nnegate: 0\n"
             "occupied_thresh: 0.65\nfree_thresh: 0.196\n");
  WriteBytes(img, "P5 4 4 255\n" + std::string(16, '\0'));
  expect_error(LoadMapYaml(dir.File("far.yaml"), GridGeometry(0.05), kLimit),
               "reaches beyond the map's bound");
  WriteBytes(dir.File("far.yaml"),
             "image: m.img\nresolution: 0.05\norigin: [1e6, 0, 0]\n"
             "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n");
  expect_error(LoadMapYaml(dir.File("far.yaml"), GridGeometry(0.05), kLimit),
               "reaches beyond the map's bound");
  // Files that are not there or not files.
  expect_error(LoadMapYaml(dir.File("none.yaml"), GridGeometry(0.05), kLimit),
               dir.File("none.yaml") + ": the map's yaml not found");
  expect_error(LoadMapYaml(dir.path().string(), GridGeometry(0.05), kLimit),
               "is not a regular file");
  WriteBytes(dir.File("lost.yaml"), YamlText("lost.pgm"));
  expect_error(
      LoadMapYaml(dir.File("lost.yaml"), GridGeometry(0.05), kLimit),
      dir.File("lost.pgm") + ": the map's image (" + dir.File("lost.yaml") + ": image) not found");
  WriteBytes(dir.File("bad.yaml"), YamlText("m.img", "mode: fancy\n"));
  expect_error(LoadMapYaml(dir.File("bad.yaml"), GridGeometry(0.05), kLimit),
               dir.File("bad.yaml") + ":7: mode:");
  expect_error(LoadMapYaml(dir.File("m.yaml"), GridGeometry(0.05), 0), "cell clamp");
}

}  // namespace
}  // namespace slam::io
