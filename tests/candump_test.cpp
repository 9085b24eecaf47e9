#include "hw_link/candump.hpp"

#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "can_test_support.hpp"

namespace slam::hw {
namespace {

using testing::Frame;
using testing::Remote;

TEST(CandumpTest, ParsesWorkedExample) {
  const auto line = ParseCandumpLine("(1700000000.123456) can0 102#2000010000402C01");
  ASSERT_EQ(line.kind, CandumpLineKind::kFrame) << line.error;
  EXPECT_EQ(line.time_us, 1700000000123456);
  EXPECT_EQ(line.interface, "can0");
  EXPECT_EQ(line.frame, Frame(0x102, {0x20, 0x00, 0x01, 0x00, 0x00, 0x40, 0x2C, 0x01}));
  EXPECT_FALSE(line.frame.extended || line.frame.remote || line.frame.fd);
}

TEST(CandumpTest, ParsesEveryFrameKind) {
  struct Case {
    std::string text;
    CanFrame frame;
  };
  const std::vector<Case> cases = {
      {"123#", Frame(0x123, {})},
      {"7FF#DEADBEEF", Frame(0x7FF, {0xDE, 0xAD, 0xBE, 0xEF})},
      {"7ff#deadbeef", Frame(0x7FF, {0xDE, 0xAD, 0xBE, 0xEF})},
      {"1F334455#0102030405060708", Frame(0x1F334455, {1, 2, 3, 4, 5, 6, 7, 8}, true)},
      {"00000102#AA", Frame(0x102, {0xAA}, true)},
      {"123#R", Remote(0x123, 0)},
      {"123#r", Remote(0x123, 0)},
      {"123#R0", Remote(0x123, 0)},
      {"123#R4", Remote(0x123, 4)},
      {"1F334455#R8", Remote(0x1F334455, 8, true)},
      {"123##0", Frame(0x123, {}, false, true)},
      {"123##1AABBCC", Frame(0x123, {0xAA, 0xBB, 0xCC}, false, true)},
      {"1F334455##F000102030405060708090A0B",
       Frame(0x1F334455, {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11}, true, true)},
  };
  for (const auto& c : cases) {
    const auto line = ParseCandumpLine("(0000000001.000002) vcan0 " + c.text);
    ASSERT_EQ(line.kind, CandumpLineKind::kFrame) << c.text << ": " << line.error;
    EXPECT_EQ(line.frame, c.frame) << c.text;
    EXPECT_EQ(line.time_us, 1000002) << c.text;
    EXPECT_EQ(line.interface, "vcan0");
  }
}

TEST(CandumpTest, IgnoresEmptyAndNonTimestampLines) {
  for (const std::string text : {"", "   ", "\t", "\r", "# a comment", "  can0 123#00",
                                 "can0  123   [2]  01 02", "x(1.000000) can0 123#00"}) {
    const auto line = ParseCandumpLine(text);
    EXPECT_EQ(line.kind, CandumpLineKind::kIgnored) << "'" << text << "'";
    EXPECT_TRUE(line.error.empty());
  }
}

TEST(CandumpTest, ToleratesBlanksAndCarriageReturn) {
  const auto line = ParseCandumpLine(" \t(1436509052.249713) \t  can0\t\t 123#DEADBEEF \t\r");
  ASSERT_EQ(line.kind, CandumpLineKind::kFrame) << line.error;
  EXPECT_EQ(line.time_us, 1436509052249713);
  EXPECT_EQ(line.interface, "can0");
  EXPECT_EQ(line.frame, Frame(0x123, {0xDE, 0xAD, 0xBE, 0xEF}));
}

TEST(CandumpTest, ShortFractionIsADecimalFraction) {
  EXPECT_EQ(ParseCandumpLine("(1.5) can0 123#").time_us, 1500000);
  EXPECT_EQ(ParseCandumpLine("(0.000001) can0 123#").time_us, 1);
  EXPECT_EQ(ParseCandumpLine("(12.04) can0 123#").time_us, 12040000);
}

TEST(CandumpTest, LargestTimestamps) {
  // 2^40 s .999999 is the largest time accepted (beyond it, a replay's timeline, which moves on
  // by up to a second a frame after a clock jump, could approach int64 microseconds).
  const auto max = ParseCandumpLine("(1099511627776.999999) can0 123#");
  ASSERT_EQ(max.kind, CandumpLineKind::kFrame) << max.error;
  EXPECT_EQ(max.time_us, 1099511627776999999);
  EXPECT_EQ(ParseCandumpLine("(1099511627777.000000) can0 123#").kind, CandumpLineKind::kError);
  EXPECT_EQ(ParseCandumpLine("(9223372036853.999999) can0 123#").kind, CandumpLineKind::kError);
  EXPECT_EQ(ParseCandumpLine("(9223372036854.000000) can0 123#").kind, CandumpLineKind::kError);
  EXPECT_EQ(ParseCandumpLine("(99999999999999999999999.000000) can0 123#").kind,
            CandumpLineKind::kError);
}

TEST(CandumpTest, RejectsMalformedLines) {
  const std::vector<std::string> bad = {
      "(",
      "()",
      "(1.000000",
      "(1.000000)",
      "(1.000000) ",
      "(1.000000) can0",
      "(1.000000) can0 ",
      "(1.000000) 123#00",
      "(1.000000)can0 123#00",
      "(abc.000000) can0 123#00",
      "(1,000000) can0 123#00",
      "(1) can0 123#00",
      "(1.) can0 123#00",
      "(.5) can0 123#00",
      "(-1.000000) can0 123#00",
      "(+1.000000) can0 123#00",
      "(1.-00000) can0 123#00",
      "(1.0000000) can0 123#00",
      "( 1.000000) can0 123#00",
      "(1.000000 ) can0 123#00",
      "(1.000000) ca#n0 123#00",
      "(1.000000) can\x01 123#00",
      "(1.000000) can0 12300",
      "(1.000000) can0 12#00",
      "(1.000000) can0 1234#00",
      "(1.000000) can0 #00",
      "(1.000000) can0 12G#00",
      "(1.000000) can0 800#00",
      "(1.000000) can0 20000000#00",
      "(1.000000) can0 20000004#0004000000000000",
      "(1.000000) can0 123#0",
      "(1.000000) can0 123#0G",
      "(1.000000) can0 123#001122334455667788",
      "(1.000000) can0 123#11.22",
      "(1.000000) can0 123#1122334455667788_9",
      "(1.000000) can0 123#R9",
      "(1.000000) can0 123#RX",
      "(1.000000) can0 123#R44",
      "(1.000000) can0 123##",
      "(1.000000) can0 123##G00",
      "(1.000000) can0 123##0001",
      "(1.000000) can0 123##0001122334455667788",
      "(1.000000) can0 123##0" + std::string(2 * 65, 'A'),
      "(1.000000) can0 123#00 extra",
      "(1.000000) can0 123#00#",
      "(1.000000) can0 123#00\r\r",
      "(1.000000) can0 123#00\n",
  };
  for (const auto& text : bad) {
    const auto line = ParseCandumpLine(text);
    EXPECT_EQ(line.kind, CandumpLineKind::kError) << text;
    EXPECT_FALSE(line.error.empty()) << text;
    EXPECT_EQ(line.error.find('\n'), std::string::npos) << text;
  }
}

TEST(CandumpTest, FormatsLikeCandump) {
  EXPECT_EQ(FormatCandumpLine(1700000000000123, "can0",
                              Frame(0x102, {0x20, 0x00, 0x01, 0x00, 0x00, 0x40, 0x2C, 0x01})),
            "(1700000000.000123) can0 102#2000010000402C01");
  EXPECT_EQ(FormatCandumpLine(5, "vcan1", Frame(0xA, {})), "(0000000000.000005) vcan1 00A#");
  EXPECT_EQ(FormatCandumpLine(12345678901000000, "can0", Remote(0x1F334455, 0, true)),
            "(12345678901.000000) can0 1F334455#R");
  EXPECT_EQ(FormatCandumpLine(0, "can0", Remote(0x123, 4)), "(0000000000.000000) can0 123#R4");
  EXPECT_EQ(FormatCandumpLine(0, "can0", Frame(0x123, {0xAB}, false, true)),
            "(0000000000.000000) can0 123##0AB");
}

void ExpectRoundTrip(int64_t time_us, const CanFrame& frame) {
  const std::string text = FormatCandumpLine(time_us, "can0", frame);
  const auto line = ParseCandumpLine(text);
  ASSERT_EQ(line.kind, CandumpLineKind::kFrame) << text << ": " << line.error;
  EXPECT_EQ(line.time_us, time_us) << text;
  EXPECT_EQ(line.interface, "can0") << text;
  EXPECT_EQ(line.frame, frame) << text;
}

TEST(CandumpTest, RoundTripsEveryFrameKind) {
  const std::vector<int64_t> times = {0, 1, 999999, 1000000, 1700000000123456, 1099511627776999999};
  const std::vector<int> fd_lengths = {0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64};
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> byte(0, 255);
  for (const int64_t t : times) {
    for (const bool extended : {false, true}) {
      const uint32_t id = extended ? kCanExtendedIdMax : kCanStandardIdMax;
      for (uint8_t len = 0; len <= kCanMaxData; ++len) {
        CanFrame f = Frame(id, std::vector<uint8_t>(len), extended);
        for (int i = 0; i < len; ++i)
          f.data[static_cast<size_t>(i)] = static_cast<uint8_t>(byte(rng));
        ExpectRoundTrip(t, f);
        ExpectRoundTrip(t, Remote(id, len, extended));
      }
      for (const int len : fd_lengths) {
        CanFrame f = Frame(id, std::vector<uint8_t>(static_cast<size_t>(len)), extended, true);
        for (int i = 0; i < len; ++i)
          f.data[static_cast<size_t>(i)] = static_cast<uint8_t>(byte(rng));
        ExpectRoundTrip(t, f);
      }
    }
  }
}

TEST(CandumpTest, RoundTripsRandomFrames) {
  std::mt19937 rng(42);
  std::uniform_int_distribution<uint32_t> std_id(0, kCanStandardIdMax);
  std::uniform_int_distribution<uint32_t> ext_id(0, kCanExtendedIdMax);
  std::uniform_int_distribution<int64_t> time(0, 4000000000000000);
  std::uniform_int_distribution<int> byte(0, 255);
  std::uniform_int_distribution<int> kind(0, 3);
  for (int n = 0; n < 2000; ++n) {
    CanFrame f;
    f.extended = (n % 2) == 1;
    f.id = f.extended ? ext_id(rng) : std_id(rng);
    switch (kind(rng)) {
      case 0:
        f.remote = true;
        f.len = static_cast<uint8_t>(byte(rng) % 9);
        break;
      case 1:
        f.fd = true;
        f.len = static_cast<uint8_t>(std::vector<int>{0, 5, 8, 12, 16, 20, 24, 32, 48,
                                                      64}[static_cast<size_t>(byte(rng) % 10)]);
        break;
      default:
        f.len = static_cast<uint8_t>(byte(rng) % 9);
    }
    if (!f.remote) {
      for (int i = 0; i < f.len; ++i)
        f.data[static_cast<size_t>(i)] = static_cast<uint8_t>(byte(rng));
    }
    ExpectRoundTrip(time(rng), f);
  }
}

}  // namespace
}  // namespace slam::hw
