#include "engine/io/robot_json.hpp"

#include <cstddef>
#include <utility>

#include "engine/io/json_reader.hpp"

namespace slam::io {
namespace {

using detail::Child;
using detail::ExpectArray;
using detail::Json;
using detail::ObjectReader;
using detail::ReadInt;
using detail::ReadNumber;

// "key": [min, max].
void ReadInterval(ObjectReader& object, const std::string& key, double& min, double& max,
                  ConfigErrors& errors) {
  const Json* value = object.Get(key, /*required=*/true);
  const std::string pointer = object.Member(key);
  if (value == nullptr || !ExpectArray(*value, pointer, 2, errors)) return;
  ReadNumber((*value)[0], Child(pointer, 0), min, errors);
  ReadNumber((*value)[1], Child(pointer, 1), max, errors);
}

void ReadBase(const Json& json, const std::string& pointer, BaseDescription& base,
              ConfigErrors& errors) {
  ObjectReader object(json, pointer, errors);
  object.Read("node", base.node, true);
  object.Read("event", base.event, true);
  object.Read("track_width_m", base.track_width_m, true);
  object.Read("ticks_per_m", base.ticks_per_m, true);
  object.Read("gyro_unit_dps", base.gyro_unit_dps, true);
  object.Read("max_speed_m_s", base.max_speed_m_s, false);
  std::string heading = "gyro";
  object.Read("heading", heading, false);
  if (heading == "encoders") {
    base.heading_from_gyro = false;
  } else if (heading != "gyro") {
    errors.push_back(
        {object.Member("heading"), "\"" + heading + "\" is not a heading source (gyro, encoders)"});
  }
  object.Finish();
}

void ReadScanner(const Json& json, const std::string& pointer, ScannerDescription& scanner,
                 ConfigErrors& errors) {
  ObjectReader object(json, pointer, errors);
  object.Read("node", scanner.node, true);
  object.Read("event", scanner.event, true);
  object.Read("sample_rate_hz", scanner.sample_rate_hz, true);
  object.Read("mount_radius_m", scanner.mount_radius_m, true);
  if (object.Get("offset_m", false) != nullptr) {
    ReadInterval(object, "offset_m", scanner.offset_x_m, scanner.offset_y_m, errors);
  }
  const Json* sensors = object.Get("sensors", true);
  const std::string sensors_pointer = object.Member("sensors");
  if (sensors != nullptr && ExpectArray(*sensors, sensors_pointer, 0, errors)) {
    scanner.sensors.clear();
    for (std::size_t i = 0; i < sensors->size(); ++i) {
      ScannerSensor sensor;
      ObjectReader entry((*sensors)[i], Child(sensors_pointer, i), errors);
      entry.Read("type", sensor.type, true);
      entry.Read("angle_deg", sensor.angle_deg, true);
      entry.Finish();
      scanner.sensors.push_back(std::move(sensor));
    }
  }
  object.Finish();
}

void ReadCalibration(const Json& json, const std::string& pointer,
                     std::vector<CalibrationPoint>& calibration, ConfigErrors& errors) {
  if (!ExpectArray(json, pointer, 0, errors)) return;
  calibration.clear();
  for (std::size_t i = 0; i < json.size(); ++i) {
    const std::string at = Child(pointer, i);
    CalibrationPoint point;
    if (ExpectArray(json[i], at, 2, errors)) {
      ReadInt(json[i][0], Child(at, 0), point.raw, errors);
      ReadNumber(json[i][1], Child(at, 1), point.distance_m, errors);
    }
    calibration.push_back(point);
  }
}

void ReadSensorType(const Json& json, const std::string& pointer, SensorTypeDescription& type,
                    ConfigErrors& errors) {
  ObjectReader object(json, pointer, errors);
  object.Read("model", type.model, true);
  std::string kind = "infrared";
  object.Read("kind", kind, false);
  if (kind == "range") {
    type.kind = SensorKind::kRange;
  } else if (kind != "infrared") {
    errors.push_back(
        {object.Member("kind"), "\"" + kind + "\" is not a sensor kind (infrared, range)"});
  }
  ReadInterval(object, "range_m", type.range_min_m, type.range_max_m, errors);
  ReadInterval(object, "use_m", type.use_min_m, type.use_max_m, errors);
  const bool infrared = type.kind == SensorKind::kInfrared;
  if (const Json* calibration = object.Get("calibration", infrared)) {
    ReadCalibration(*calibration, object.Member("calibration"), type.calibration, errors);
  }
  if (const Json* beams = object.Get("beams", !infrared)) {
    ObjectReader beam_object(*beams, object.Member("beams"), errors);
    beam_object.Read("first_deg", type.beams.first_deg, true);
    beam_object.Read("increment_deg", type.beams.increment_deg, true);
    beam_object.Read("count", type.beams.count, true);
    beam_object.Finish();
  }
  object.Read("no_return_m", type.no_return_m, false);
  if (const Json* sigma = object.Get("sigma_m", false)) {
    const std::string at = object.Member("sigma_m");
    if (ExpectArray(*sigma, at, type.sigma_m.size(), errors)) {
      for (std::size_t k = 0; k < type.sigma_m.size(); ++k) {
        ReadNumber((*sigma)[k], Child(at, k), type.sigma_m[k], errors);
      }
    }
  }
  object.Finish();
}

}  // namespace

Result<RobotDescription> RobotFromJson(const nlohmann::json& json) {
  ConfigErrors errors;
  RobotDescription robot;
  ObjectReader root(json, "", errors);
  root.Read("name", robot.name, true);
  if (const Json* base = root.Get("base", true)) ReadBase(*base, "/base", robot.base, errors);
  if (const Json* scanner = root.Get("scanner", true)) {
    ReadScanner(*scanner, "/scanner", robot.scanner, errors);
  }
  if (const Json* types = root.Get("sensor_types", true)) {
    ObjectReader types_object(*types, "/sensor_types", errors);
    if (types_object.is_object()) {
      for (const auto& [name, value] : types->items()) {
        types_object.Get(name, true);  // every name is a valid key
        ReadSensorType(value, types_object.Member(name), robot.sensor_types[name], errors);
      }
    }
  }
  root.Finish();
  if (!errors.empty()) return errors;  // validating a half-read description would only confuse
  errors = Validate(robot);
  if (!errors.empty()) return errors;
  return robot;
}

Result<RobotDescription> LoadRobot(const std::string& path) {
  return detail::LoadJsonFile<RobotDescription>(path, RobotFromJson);
}

nlohmann::json RobotToJson(const RobotDescription& robot) {
  Json sensors = Json::array();
  for (const ScannerSensor& sensor : robot.scanner.sensors) {
    sensors.push_back({{"type", sensor.type}, {"angle_deg", sensor.angle_deg}});
  }
  Json types = Json::object();
  for (const auto& [name, type] : robot.sensor_types) {
    Json calibration = Json::array();
    for (const CalibrationPoint& point : type.calibration) {
      calibration.push_back(Json::array({point.raw, point.distance_m}));
    }
    types[name] = {
        {"model", type.model},
        {"range_m", Json::array({type.range_min_m, type.range_max_m})},
        {"use_m", Json::array({type.use_min_m, type.use_max_m})},
        {"sigma_m", Json::array({type.sigma_m[0], type.sigma_m[1], type.sigma_m[2]})},
    };
    if (type.kind == SensorKind::kInfrared) {
      types[name]["calibration"] = std::move(calibration);
    } else {
      types[name]["kind"] = "range";
      types[name]["beams"] = {{"first_deg", type.beams.first_deg},
                              {"increment_deg", type.beams.increment_deg},
                              {"count", type.beams.count}};
      if (type.no_return_m > 0.0) types[name]["no_return_m"] = type.no_return_m;
    }
  }
  const BaseDescription& base = robot.base;
  const ScannerDescription& scanner = robot.scanner;
  Json json = {
      {"name", robot.name},
      {"base",
       {{"node", base.node},
        {"event", base.event},
        {"track_width_m", base.track_width_m},
        {"ticks_per_m", base.ticks_per_m},
        {"gyro_unit_dps", base.gyro_unit_dps}}},
      {"scanner",
       {{"node", scanner.node},
        {"event", scanner.event},
        {"sample_rate_hz", scanner.sample_rate_hz},
        {"mount_radius_m", scanner.mount_radius_m},
        {"sensors", std::move(sensors)}}},
      {"sensor_types", std::move(types)},
  };
  // Optional: written only when it differs from the default, so that descriptions without it
  // read and write back unchanged.
  if (base.max_speed_m_s != BaseDescription{}.max_speed_m_s) {
    json["base"]["max_speed_m_s"] = base.max_speed_m_s;
  }
  if (!base.heading_from_gyro) json["base"]["heading"] = "encoders";
  if (scanner.offset_x_m != 0.0 || scanner.offset_y_m != 0.0) {
    json["scanner"]["offset_m"] = Json::array({scanner.offset_x_m, scanner.offset_y_m});
  }
  return json;
}

}  // namespace slam::io
