#include "server/source_spec.hpp"

#include <gtest/gtest.h>

#include <memory>
#include <string>
#include <variant>

#include "sim/virtual_marxbot.hpp"
#include "test_support.hpp"

namespace slam::server {
namespace {

std::string ErrorOf(const hw::OpenResult& result) { return result.Message(); }

TEST(SourceSpecTest, OpensTheVirtualMarxbotAndUdp) {
  const RobotDescription robot = testing::ShippedRobot();
  const hw::OpenResult sim = OpenSourceSpec("sim:rooms", robot);
  ASSERT_TRUE(sim.ok()) << ErrorOf(sim);
  EXPECT_EQ(sim.value()->Describe(), "sim:rooms");
  // A tracked robot's odometry unless told otherwise, as slam-sim's.
  const auto* virtual_marxbot = dynamic_cast<const sim::VirtualMarxbotSource*>(sim.value().get());
  ASSERT_NE(virtual_marxbot, nullptr);
  EXPECT_EQ(virtual_marxbot->odometry_profile(), "tracked");
  SourceSpecOptions gentle;
  gentle.odometry = sim::OdometryProfile::kGentle;
  const hw::OpenResult original = OpenSourceSpec("sim:rooms", robot, gentle);
  ASSERT_TRUE(original.ok()) << ErrorOf(original);
  EXPECT_EQ(dynamic_cast<const sim::VirtualMarxbotSource&>(*original.value()).odometry_profile(),
            "gentle");

  const hw::OpenResult udp = OpenSourceSpec("udp:127.0.0.1:0", robot);
  ASSERT_TRUE(udp.ok()) << ErrorOf(udp);
  EXPECT_GT(hw::BoundUdpPort(*udp.value()), 0);
}

TEST(SourceSpecTest, UdpListensOnLoopbackUnlessToldAndCanNameItsSender) {
  // udp:PORT once listened on every address: anyone on the network could send odometry.
  const RobotDescription robot = testing::ShippedRobot();
  const hw::OpenResult plain = OpenSourceSpec("udp:0", robot);
  ASSERT_TRUE(plain.ok()) << ErrorOf(plain);
  const hw::FrameSource& source = *plain.value();
  EXPECT_EQ(source.Describe(), "udp:127.0.0.1:" + std::to_string(hw::BoundUdpPort(source)));

  const hw::OpenResult any = OpenSourceSpec("udp:0.0.0.0:0,from=192.168.1.7", robot);
  ASSERT_TRUE(any.ok()) << ErrorOf(any);
  const hw::FrameSource& restricted = *any.value();
  EXPECT_EQ(restricted.Describe(),
            "udp:0.0.0.0:" + std::to_string(hw::BoundUdpPort(restricted)) + ",from=192.168.1.7");
}

TEST(SourceSpecTest, BadSpecsGiveClearErrors) {
  const RobotDescription robot = testing::ShippedRobot();
  const struct {
    const char* spec;
    const char* expected;
  } cases[] = {
      {"rooms", "expected sim:WORLD"},
      {"sim:", "expected sim:WORLD"},
      {"tcp:1234", "unknown kind 'tcp'"},
      {"udp:70000", "'70000' is not a UDP port"},
      {"udp:12ab", "'12ab' is not a UDP port"},
      {"udp:0,to=1.2.3.4", "unknown UDP option 'to=1.2.3.4'"},
      {"udp:0,from=", "unknown UDP option 'from='"},
      {"udp:127.0.0.1:0,from=robot", "invalid IPv4 sender address 'robot'"},
      {"sim:/nonexistent/world.json", "/nonexistent/world.json"},
      {"candump:/nonexistent/can.log", "/nonexistent/can.log"},
  };
  for (const auto& c : cases) {
    const std::string error = ErrorOf(OpenSourceSpec(c.spec, robot));
    EXPECT_NE(error.find(c.expected), std::string::npos) << c.spec << ": " << error;
  }
}

TEST(SourceSpecTest, SocketCanFailsClearlyWithoutAfCan) {
  if (hw::SocketCanAvailable()) GTEST_SKIP() << "this kernel has AF_CAN";
  const std::string error = ErrorOf(OpenSourceSpec("socketcan:can0", testing::ShippedRobot()));
  EXPECT_NE(error.find("AF_CAN"), std::string::npos) << error;
}

}  // namespace
}  // namespace slam::server
