#include "hw_link/event_decoder.hpp"

#include <gtest/gtest.h>

#include <cstdint>

#include "test_support.hpp"

namespace slam::hw {
namespace {

TEST(EventDecoderTest, OdometryRoundTripsWithExtremeValues) {
  const RobotDescription robot = testing::ShippedRobot();
  EventDecoder decoder(robot);
  for (const int32_t ticks : {0, 1, -1, 65535, 65536, -65536, INT32_MAX, INT32_MIN}) {
    OdometryReading r;
    r.t = 12.5;
    r.seq = 65535;
    r.left_ticks = ticks;
    r.right_ticks = -ticks - 1;
    r.gyro_raw = -32768;
    const auto event = decoder.Decode(EncodeOdometry(robot, r));
    ASSERT_TRUE(event);
    EXPECT_EQ(std::get<OdometryReading>(*event), r);
  }
  EXPECT_EQ(decoder.counters().odometry, 8u);
}

TEST(EventDecoderTest, ScannerRoundTrips) {
  const RobotDescription robot = testing::ShippedRobot();
  EventDecoder decoder(robot);
  ScannerReading r;
  r.t = 3.0;
  r.seq = 7;
  r.angle_raw = 0xFFFF;
  r.raw = {0, 1023, 512, 77};
  r.rectifier_mv = 6500;
  const AsebaMessage message = EncodeScanner(robot, r);
  EXPECT_EQ(message.source, robot.scanner.node);
  EXPECT_EQ(message.type, robot.scanner.event);
  EXPECT_EQ(message.payload.size(), 2u * kScannerWords);
  const auto event = decoder.Decode(message);
  ASSERT_TRUE(event);
  EXPECT_EQ(std::get<ScannerReading>(*event), r);
}

TEST(EventDecoderTest, CountsWhatItCannotDecode) {
  const RobotDescription robot = testing::ShippedRobot();
  EventDecoder decoder(robot);
  AsebaMessage unknown_node{99, static_cast<uint16_t>(robot.base.event), {1, 2}, 0.0};
  AsebaMessage unknown_type{static_cast<uint8_t>(robot.base.node), 0x9001, {}, 0.0};
  AsebaMessage short_odometry = EncodeOdometry(robot, {});
  short_odometry.payload.pop_back();
  AsebaMessage long_scan = EncodeScanner(robot, {});
  long_scan.payload.push_back(0);
  long_scan.payload.push_back(0);
  // The base's event type sent by the scanner node is not an odometry event.
  AsebaMessage swapped = EncodeOdometry(robot, {});
  swapped.source = static_cast<uint8_t>(robot.scanner.node);
  for (const auto& m : {unknown_node, unknown_type, short_odometry, long_scan, swapped}) {
    EXPECT_FALSE(decoder.Decode(m));
  }
  EXPECT_EQ(decoder.counters().messages, 5u);
  EXPECT_EQ(decoder.counters().unknown_node, 1u);
  EXPECT_EQ(decoder.counters().unknown_type, 2u);
  EXPECT_EQ(decoder.counters().bad_size, 2u);
  EXPECT_EQ(decoder.counters().odometry + decoder.counters().scanner, 0u);
}

TEST(EventDecoderTest, RawReadingsBeyondTheAdcAreCounted) {
  // A 10-bit ADC reads at most 1023: larger values were dropped by the sensor model uncounted.
  const RobotDescription robot = testing::ShippedRobot();
  EventDecoder decoder(robot);
  ScannerReading r;
  r.raw = {1023, 1024, 65535, 5};
  const auto event = decoder.Decode(EncodeScanner(robot, r));
  ASSERT_TRUE(event);  // the sample is kept: its other sensors are good
  EXPECT_EQ(std::get<ScannerReading>(*event).raw, r.raw);
  EXPECT_EQ(decoder.counters().raw_out_of_range, 2u);
  EXPECT_EQ(decoder.counters().scanner, 1u);
}

TEST(EventDecoderTest, FollowsTheRobotDescription) {
  RobotDescription robot = testing::ShippedRobot();
  robot.base.node = 5;
  robot.base.event = 0x123;
  EventDecoder decoder(robot);
  OdometryReading r;
  r.left_ticks = 42;
  const AsebaMessage message = EncodeOdometry(robot, r);
  EXPECT_EQ(message.source, 5);
  EXPECT_EQ(message.type, 0x123);
  EXPECT_TRUE(decoder.Decode(message));
  EventDecoder default_decoder(testing::ShippedRobot());
  EXPECT_FALSE(default_decoder.Decode(message));
}

}  // namespace
}  // namespace slam::hw
