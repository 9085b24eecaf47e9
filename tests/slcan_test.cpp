#include "hw_link/slcan.hpp"

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

struct Result {
  std::vector<SlcanFrame> frames;
  SlcanCounters counters;
};

Result FeedWhole(std::string_view bytes) {
  SlcanParser parser;
  Result r;
  parser.Feed(bytes, r.frames);
  r.counters = parser.counters();
  return r;
}

TEST(SlcanTest, ParsesFrameLines) {
  const auto r = FeedWhole(
      "t10282000010000402C01\r"
      "t20280002 1801EA016419\r"  // a blank inside: bad line
      "t7ff0\r"
      "T1F3344553AABBCC\r"
      "r1234\r"
      "R1F3344558\r");
  ASSERT_EQ(r.frames.size(), 5u);
  EXPECT_EQ(r.frames[0].frame, Frame(0x102, {0x20, 0x00, 0x01, 0x00, 0x00, 0x40, 0x2C, 0x01}));
  EXPECT_EQ(r.frames[1].frame, Frame(0x7FF, {}));
  EXPECT_EQ(r.frames[2].frame, Frame(0x1F334455, {0xAA, 0xBB, 0xCC}, true));
  EXPECT_EQ(r.frames[3].frame, Remote(0x123, 4));
  EXPECT_EQ(r.frames[4].frame, Remote(0x1F334455, 8, true));
  for (const auto& f : r.frames) EXPECT_FALSE(f.timestamp_ms.has_value());
  EXPECT_EQ(r.counters.frames, 5u);
  EXPECT_EQ(r.counters.bad_lines, 1u);
  EXPECT_EQ(r.counters.acks, 0u);
}

TEST(SlcanTest, ParsesTimestamps) {
  const auto r = FeedWhole("t1230EA5F\rt1231AA1122\rT000000012AABB0000\rr1238fFfF\r");
  ASSERT_EQ(r.frames.size(), 3u);
  EXPECT_EQ(r.frames[0].timestamp_ms, 59999);
  EXPECT_EQ(r.frames[0].frame, Frame(0x123, {}));
  EXPECT_EQ(r.frames[1].timestamp_ms, 0x1122);
  EXPECT_EQ(r.frames[1].frame, Frame(0x123, {0xAA}));
  EXPECT_EQ(r.frames[2].timestamp_ms, 0);
  EXPECT_EQ(r.frames[2].frame, Frame(0x1, {0xAA, 0xBB}, true));
  // "r1238fFfF": 0xFFFF >= 60000.
  EXPECT_EQ(r.counters.bad_lines, 1u);
}

TEST(SlcanTest, CountsRepliesWithOrWithoutLineEnd) {
  const auto r = FeedWhole("\r\a\rz\rZ\r\a\a");
  EXPECT_TRUE(r.frames.empty());
  EXPECT_EQ(r.counters.acks, 4u);  // "\r", the '\r' after the bell, "z\r", "Z\r"
  EXPECT_EQ(r.counters.nacks, 3u);
  EXPECT_EQ(r.counters.bad_lines, 0u);
  EXPECT_EQ(r.counters.bytes, 9u);
}

TEST(SlcanTest, BellCutsAnUnfinishedLine) {
  const auto r = FeedWhole("t12\at1230\r");
  ASSERT_EQ(r.frames.size(), 1u);
  EXPECT_EQ(r.counters.nacks, 1u);
  EXPECT_EQ(r.counters.bad_lines, 1u);
  EXPECT_TRUE(r.frames[0].after_bad_line);  // the cut line may have been a frame
}

TEST(SlcanTest, TheFrameAfterABadLineSaysSo) {
  const auto r = FeedWhole("t1230\rgarbage\rt1230\rt1230\r" + std::string(100, 't') + "\rt1230\r");
  ASSERT_EQ(r.frames.size(), 4u);
  EXPECT_EQ(r.counters.bad_lines, 2u);
  EXPECT_FALSE(r.frames[0].after_bad_line);
  EXPECT_TRUE(r.frames[1].after_bad_line);
  EXPECT_FALSE(r.frames[2].after_bad_line);
  EXPECT_TRUE(r.frames[3].after_bad_line);  // an overlong line
}

TEST(SlcanTest, LineFeedEndsLinesButCrLfIsOneLineEnd) {
  auto r = FeedWhole("t1230\nt1231AA\r\nt1230\r\n\r\n");
  EXPECT_EQ(r.frames.size(), 3u);
  EXPECT_EQ(r.counters.acks, 1u);  // only the empty line "\r\n"
  r = FeedWhole("\n\n\r\n\n\r");
  EXPECT_EQ(r.counters.acks, 5u);  // "\n", "\n", "\r\n", "\n", "\r"
  r = FeedWhole("z\n");
  EXPECT_EQ(r.counters.acks, 1u);
  // A '\n' after a '\r' from an earlier Feed still belongs to it.
  SlcanParser parser;
  std::vector<SlcanFrame> frames;
  parser.Feed("t1230\r", frames);
  parser.Feed("\n", frames);
  EXPECT_EQ(frames.size(), 1u);
  EXPECT_EQ(parser.counters().acks, 0u);
}

TEST(SlcanTest, CountsBadLines) {
  const std::vector<std::string> bad = {
      "x",           "zz",        "V1013",
      "t",           "t12",       "t123",
      "t12G0",       "t1231",     "t1231A",
      "t1231AAB",    "t1232AA",   "t1231GG",
      "t1239",       "t123A",     "t8000",
      "T2000000000", "T1234567",  "T12345678",
      "r12",         "r1239",     "r1230AA",
      "R200000000",  "t1230EA60", "t1230FFFF",
      "t12301",      "t123012",   "t1230123",
      "t123012345",  "t1230XYZW", "t 1230",
      " t1230",      "t1230 ",    std::string("\0t1230", 6),
      "S8",          "O",         "T1F3344551AA0",
  };
  for (const auto& line : bad) {
    const auto r = FeedWhole(line + "\r");
    EXPECT_TRUE(r.frames.empty()) << line;
    EXPECT_EQ(r.counters.bad_lines, 1u) << line;
    EXPECT_EQ(r.counters.acks, 0u) << line;
  }
}

TEST(SlcanTest, OverlongLinesAreCountedOnceAndSkipped) {
  // The longest valid line: extended id, 8 data bytes, time stamp (30 characters).
  const std::string valid = "T1F334455800112233445566771234";
  ASSERT_EQ(valid.size(), 30u);
  auto r = FeedWhole(valid + "\r");
  ASSERT_EQ(r.frames.size(), 1u);
  EXPECT_EQ(r.frames[0].timestamp_ms, 0x1234);

  r = FeedWhole(valid + "0\r" + std::string(1000, 't') + "\rt1230\r\r");
  EXPECT_EQ(r.counters.bad_lines, 2u);
  EXPECT_EQ(r.counters.frames, 1u);
  EXPECT_EQ(r.counters.acks, 1u);

  // A bell ends the skipping too.
  r = FeedWhole(std::string(100, '5') + "\a\r");
  EXPECT_EQ(r.counters.bad_lines, 1u);
  EXPECT_EQ(r.counters.nacks, 1u);
  EXPECT_EQ(r.counters.acks, 1u);
}

// A stream with frames, replies, garbage, overlong lines and both line ends.
std::string MixedStream() {
  std::string s;
  s += "t10282000010000402C01\r";
  s += "t202800021801EA0164191234\r";
  s += "\r\a\az\rZ\r";
  s += "garbage!\r\n";
  s += "T1F3344553AABBCC\r\n";
  s += "r1234\n";
  s += "R1F33445580000\r";
  s += std::string(70, 'x') + "\r\n";
  s += "t12\a";
  s += "t1239\r";
  s += "t8000\r";
  s += "t1230EA60\r";
  s += "\n\n";
  s += "t7FF1FF\r";
  s += "t1238001122334455667700FF\r";
  s += "T000000010\r";
  s += "\r\n\r\n";
  s += "t10";  // unfinished at the end
  return s;
}

TEST(SlcanTest, MixedStreamCounts) {
  const auto r = FeedWhole(MixedStream());
  EXPECT_EQ(r.counters.frames, 8u);
  // "\r" "z\r" "Z\r", one "\n" (the other ends "t1230EA60\r"), "\r\n" "\r\n".
  EXPECT_EQ(r.counters.acks, 6u);
  EXPECT_EQ(r.counters.nacks, 3u);
  EXPECT_EQ(r.counters.bad_lines, 6u);  // garbage, overlong, "t12", "t1239", "t8000", EA60
  EXPECT_EQ(r.counters.bytes, MixedStream().size());
  ASSERT_EQ(r.frames.size(), 8u);
  EXPECT_EQ(r.frames[1].timestamp_ms, 0x1234);
  EXPECT_EQ(r.frames[4].timestamp_ms, 0);
}

TEST(SlcanTest, SplittingAnywhereChangesNothing) {
  const std::string stream = MixedStream();
  const auto whole = FeedWhole(stream);
  for (size_t cut = 0; cut <= stream.size(); ++cut) {
    SlcanParser parser;
    std::vector<SlcanFrame> frames;
    parser.Feed(std::string_view(stream).substr(0, cut), frames);
    parser.Feed(std::string_view(stream).substr(cut), frames);
    ASSERT_TRUE(frames == whole.frames) << "cut at " << cut;
    ASSERT_TRUE(parser.counters() == whole.counters) << "cut at " << cut;
  }
  SlcanParser parser;
  std::vector<SlcanFrame> frames;
  for (const char c : stream) parser.Feed(std::string_view(&c, 1), frames);
  EXPECT_TRUE(frames == whole.frames);
  EXPECT_TRUE(parser.counters() == whole.counters);
}

TEST(SlcanTest, RandomChunksChangeNothing) {
  std::mt19937 rng(1234);
  std::string stream;
  for (int i = 0; i < 20; ++i) stream += MixedStream();
  const auto whole = FeedWhole(stream);
  for (int trial = 0; trial < 50; ++trial) {
    SlcanParser parser;
    std::vector<SlcanFrame> frames;
    size_t pos = 0;
    while (pos < stream.size()) {
      const size_t n = std::uniform_int_distribution<size_t>(0, 40)(rng);
      parser.Feed(std::string_view(stream).substr(pos, n), frames);
      pos += n;
    }
    ASSERT_TRUE(frames == whole.frames);
    ASSERT_TRUE(parser.counters() == whole.counters);
  }
}

TEST(SlcanTest, FormatsAdapterLines) {
  EXPECT_EQ(FormatSlcanFrame(Frame(0x102, {0x20, 0x00, 0x01, 0x00, 0x00, 0x40, 0x2C, 0x01})),
            "t10282000010000402C01\r");
  EXPECT_EQ(FormatSlcanFrame(Frame(0x1F334455, {0xAB}, true), 0x1234), "T1F3344551AB1234\r");
  EXPECT_EQ(FormatSlcanFrame(Remote(0x7, 2)), "r0072\r");
  EXPECT_EQ(FormatSlcanFrame(Remote(0x7, 0, true), 59999), "R000000070EA5F\r");
  EXPECT_EQ(SlcanOpenCommands(), "C\rS8\rO\r");
}

TEST(SlcanTest, RoundTrips) {
  std::mt19937 rng(99);
  std::uniform_int_distribution<int> byte(0, 255);
  std::vector<SlcanFrame> expected;
  std::string stream;
  for (const bool extended : {false, true}) {
    for (const bool remote : {false, true}) {
      for (uint8_t len = 0; len <= kCanMaxData; ++len) {
        for (const auto stamp : {std::optional<uint16_t>{}, std::optional<uint16_t>{0},
                                 std::optional<uint16_t>{59999}}) {
          CanFrame f;
          f.extended = extended;
          f.remote = remote;
          f.len = len;
          f.id = extended ? kCanExtendedIdMax - len : kCanStandardIdMax - len;
          if (!remote) {
            for (size_t i = 0; i < len; ++i) f.data[i] = static_cast<uint8_t>(byte(rng));
          }
          const std::string line = FormatSlcanFrame(f, stamp);
          const auto r = FeedWhole(line);
          ASSERT_EQ(r.frames.size(), 1u) << line;
          EXPECT_EQ(r.frames[0].frame, f) << line;
          EXPECT_EQ(r.frames[0].timestamp_ms, stamp) << line;
          expected.push_back({f, stamp});
          stream += line;
        }
      }
    }
  }
  const auto all = FeedWhole(stream);
  EXPECT_TRUE(all.frames == expected);
  EXPECT_EQ(all.counters.bad_lines, 0u);
}

}  // namespace
}  // namespace slam::hw
