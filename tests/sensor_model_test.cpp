#include "engine/sensor_model.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "engine/cell_encoding.hpp"
#include "engine/update_ray.hpp"

namespace slam {
namespace {

// A hand-made long-range sensor: 1/d is linear in raw between the points.
SensorTypeDescription LongSensor() {
  SensorTypeDescription t;
  t.model = "test-long";
  t.range_min_m = 0.20;
  t.range_max_m = 1.50;
  t.use_min_m = 0.35;
  t.use_max_m = 1.00;
  t.calibration = {{760, 0.20}, {500, 0.40}, {300, 0.80}, {200, 1.50}};
  t.sigma_m = {0.005, 0.0, 0.02};
  return t;
}

SensorTypeDescription ShortSensor() {
  SensorTypeDescription t;
  t.model = "test-short";
  t.range_min_m = 0.04;
  t.range_max_m = 0.30;
  t.use_min_m = 0.0;
  t.use_max_m = 0.35;
  t.calibration = {{822, 0.04}, {400, 0.10}, {150, 0.35}};
  t.sigma_m = {0.003, 0.0, 0.02};
  return t;
}

TEST(Calibration, InterpolatesInverseDistanceAndRejectsOutsideTheTable) {
  const auto table = LongSensor().calibration;
  EXPECT_DOUBLE_EQ(*CalibratedDistance(table, 760), 0.20);
  EXPECT_DOUBLE_EQ(*CalibratedDistance(table, 500), 0.40);
  // Half-way in raw between 500 (1/0.4 = 2.5) and 300 (1/0.8 = 1.25): 1/d = 1.875.
  EXPECT_NEAR(*CalibratedDistance(table, 400), 1.0 / 1.875, 1e-12);
  EXPECT_FALSE(CalibratedDistance(table, 761));  // non-injective near zone
  EXPECT_FALSE(CalibratedDistance(table, 199));  // floor beyond range
  for (int raw = 200; raw <= 760; raw += 7) {
    EXPECT_EQ(CalibratedRaw(table, *CalibratedDistance(table, raw)), raw);
  }
  EXPECT_EQ(CalibratedRaw(table, 0.01), 760);
  EXPECT_EQ(CalibratedRaw(table, 9.0), 200);
}

TEST(SensorModel, UsesOnlyReadingsInsideTheUseWindow) {
  const SensorModel long_model(LongSensor(), {}, 0.01);
  EXPECT_FALSE(long_model.Distance(760));  // 0.20 m: calibrated but below the 0.35 m use window
  EXPECT_FALSE(long_model.Update(760));
  EXPECT_TRUE(long_model.Distance(500));
  EXPECT_FALSE(long_model.Distance(250));  // beyond 1.0 m
  EXPECT_FALSE(long_model.Distance(900));  // above the table: never trusted
  EXPECT_FALSE(long_model.Distance(1023));
  EXPECT_FALSE(long_model.Distance(4000));  // not a 10-bit value
  const SensorModel short_model(ShortSensor(), {}, 0.01);
  EXPECT_NEAR(*short_model.Distance(822), 0.04, 1e-12);
  EXPECT_FALSE(short_model.Distance(823));
  EXPECT_FALSE(short_model.Distance(149));
  EXPECT_NEAR(short_model.Sigma(0.3), 0.003 + 0.02 * 0.09, 1e-12);
}

// Applies a reading along +x from the centre of cell 0: cell x is crossed over
// [x - 1/2, x + 1/2] cells. Cells crossed entirely before the reading are free, the cell holding
// the measured point and those up to the occupied depth behind it are occupied, the rest untouched.
void ExpectFreeOccupiedUntouched(const SensorModel& model, int raw, const UpdateModelConfig& update,
                                 double resolution) {
  OccupancyGrid grid(GridGeometry(resolution), kLogOddsLimit);
  const std::optional<UpdateProfile> profile = model.Update(static_cast<uint16_t>(raw));
  ASSERT_TRUE(profile.has_value());
  ApplyUpdateRay(grid, {resolution / 2, resolution / 2}, 0.0, *profile);
  const double d = *model.Distance(static_cast<uint16_t>(raw));
  const double depth = std::max(update.occupied_depth_cells * resolution,
                                update.occupied_sigma_factor * model.Sigma(d));
  const double tolerance = resolution / 8;  // the table's bins
  const int free_value = EncodeLogOdds(update.free_logodds);
  const int occupied_value = EncodeLogOdds(update.occupied_logodds);
  const int holding = static_cast<int>(std::floor(d / resolution + 0.5));  // cell of the point
  EXPECT_EQ(grid.At({holding, 0}), occupied_value) << "the cell holding the measured point";
  int free = 0, occupied = 0;
  for (int x = 0; x < static_cast<int>(2.0 / resolution); ++x) {
    const double exit = (x + 0.5) * resolution, enter = std::max(0.0, (x - 0.5) * resolution);
    const int value = grid.At({x, 0});
    if (exit < d - tolerance) {
      EXPECT_EQ(value, free_value) << "cell " << x << " before the reading";
    } else if (enter < d + depth - tolerance && exit > d + tolerance) {
      EXPECT_EQ(value, occupied_value) << "cell " << x << " at the reading";
    } else if (enter > d + depth + tolerance) {
      EXPECT_EQ(value, 0) << "cell " << x << " beyond the reading";
    }
    free += value == free_value;
    occupied += value == occupied_value;
  }
  EXPECT_GE(free, static_cast<int>(d / resolution) - 1);
  EXPECT_GE(occupied, 1);
  EXPECT_LE(occupied, static_cast<int>(depth / resolution) + 2);
  EXPECT_EQ(grid.At({0, 1}), 0);  // nothing off the ray
}

// At any angle, the cell holding the measured point is occupied and the ray's cells before it
// are free.
TEST(SensorModel, TheCellHoldingTheReadingIsOccupiedAtEveryAngle) {
  const UpdateModelConfig update;
  const SensorModel model(LongSensor(), update, 0.01);
  const double d = *model.Distance(420);
  for (double deg = 0; deg < 360; deg += 7.3) {
    OccupancyGrid grid(GridGeometry(0.01), kLogOddsLimit);
    const Vec2 origin(0.0031, -0.0047);
    const double a = DegToRad(deg);
    ApplyUpdateRay(grid, origin, a, *model.Update(420));
    const Vec2 point = origin + d * Vec2(std::cos(a), std::sin(a));
    EXPECT_EQ(grid.At(grid.geometry().CellOf(point)), EncodeLogOdds(update.occupied_logodds))
        << deg;
    const Vec2 before = origin + (d - 0.015) * Vec2(std::cos(a), std::sin(a));
    EXPECT_EQ(grid.At(grid.geometry().CellOf(before)), EncodeLogOdds(update.free_logodds)) << deg;
  }
}

TEST(SensorModel, UpdateTablesMarkFreeThenOccupiedThenNothing) {
  const UpdateModelConfig update;
  for (int raw : {500, 420, 300})
    ExpectFreeOccupiedUntouched(SensorModel(LongSensor(), update, 0.01), raw, update, 0.01);
  for (int raw : {822, 600, 400, 200})
    ExpectFreeOccupiedUntouched(SensorModel(ShortSensor(), update, 0.01), raw, update, 0.01);
  UpdateModelConfig wide;
  wide.occupied_sigma_factor = 2.0;
  wide.occupied_depth_cells = 3.0;
  ExpectFreeOccupiedUntouched(SensorModel(LongSensor(), wide, 0.02), 320, wide, 0.02);
}

}  // namespace
}  // namespace slam
