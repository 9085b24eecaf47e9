#include "hw_link/cannelloni.hpp"

#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <string>
#include <variant>
#include <vector>

#include "can_test_support.hpp"

namespace slam::hw {
namespace {

using testing::Frame;
using testing::Remote;

// The decode error of `bytes`, or "" when they decode.
std::string ErrorOf(const std::vector<uint8_t>& bytes) {
  const auto r = DecodeCannelloni(bytes);
  return r.Message();
}

TEST(CannelloniTest, EncodesBigEndianLayout) {
  const std::vector<CanFrame> frames = {
      Frame(0x102, {0x20, 0x00}),
      Frame(0x1F334455, {0xAA}, true),
      Remote(0x7FF, 4),
      Frame(0x123, {0x01, 0x02, 0x03}, false, true),
  };
  const std::vector<uint8_t> expected = {
      2,    0,    0x2A, 0x00, 0x04,                    // version, op, sequence, count
      0x00, 0x00, 0x01, 0x02, 0x02, 0x20, 0x00,        // standard
      0x9F, 0x33, 0x44, 0x55, 0x01, 0xAA,              // extended (0x80000000)
      0x40, 0x00, 0x07, 0xFF, 0x04,                    // remote (0x40000000): no data
      0x00, 0x00, 0x01, 0x23, 0x83, 0x00, 1,    2, 3,  // FD: 0x80 | len, flags, data
  };
  EXPECT_EQ(EncodeCannelloni(0x2A, frames), expected);
  const auto decoded = DecodeCannelloni(expected);
  ASSERT_TRUE(decoded.ok()) << decoded.Message();
  const auto& datagram = decoded.value();
  EXPECT_EQ(datagram.sequence, 0x2A);
  EXPECT_EQ(datagram.frames, frames);
}

TEST(CannelloniTest, EmptyDatagram) {
  const auto bytes = EncodeCannelloni(7, {});
  EXPECT_EQ(bytes, (std::vector<uint8_t>{2, 0, 7, 0, 0}));
  const auto decoded = DecodeCannelloni(bytes);
  ASSERT_TRUE(decoded.ok());
  EXPECT_TRUE(decoded.value().frames.empty());
}

TEST(CannelloniTest, RoundTripsMixedFrames) {
  std::mt19937 rng(5);
  std::uniform_int_distribution<int> byte(0, 255);
  std::uniform_int_distribution<uint32_t> std_id(0, kCanStandardIdMax);
  std::uniform_int_distribution<uint32_t> ext_id(0, kCanExtendedIdMax);
  const std::vector<uint8_t> fd_lengths = {0, 3, 8, 12, 16, 20, 24, 32, 48, 64};
  for (int round = 0; round < 200; ++round) {
    std::vector<CanFrame> frames(static_cast<size_t>(byte(rng) % 20));
    for (auto& f : frames) {
      f.extended = byte(rng) % 2 == 1;
      f.id = f.extended ? ext_id(rng) : std_id(rng);
      const int kind = byte(rng) % 3;
      f.remote = kind == 0;
      f.fd = kind == 1;
      f.len = f.fd ? fd_lengths[static_cast<size_t>(byte(rng)) % fd_lengths.size()]
                   : static_cast<uint8_t>(byte(rng) % 9);
      if (!f.remote) {
        for (size_t i = 0; i < f.len; ++i) f.data[i] = static_cast<uint8_t>(byte(rng));
      }
    }
    const auto sequence = static_cast<uint8_t>(round);
    const auto decoded = DecodeCannelloni(EncodeCannelloni(sequence, frames));
    ASSERT_TRUE(decoded.ok()) << decoded.Message();
    EXPECT_EQ(decoded.value().sequence, sequence);
    EXPECT_EQ(decoded.value().frames, frames);
  }
}

TEST(CannelloniTest, DecodeIgnoresFdFlagsAndRemoteData) {
  // The FD flags byte (0x05 here) is dropped; a remote frame's length is not followed by data.
  const std::vector<uint8_t> bytes = {2,    0,    1,    0,    2, 0, 0,    0, 0x10,
                                      0x81, 0x05, 0xEE, 0x40, 0, 0, 0x10, 8};
  const auto decoded = DecodeCannelloni(bytes);
  ASSERT_TRUE(decoded.ok()) << decoded.Message();
  const auto& frames = decoded.value().frames;
  ASSERT_EQ(frames.size(), 2u);
  EXPECT_EQ(frames[0], Frame(0x10, {0xEE}, false, true));
  EXPECT_EQ(frames[1], Remote(0x10, 8));
}

TEST(CannelloniTest, RejectsEveryMalformedDatagram) {
  const std::vector<uint8_t> one = {2, 0, 0, 0, 1, 0, 0, 1, 0x23, 2, 0xAA, 0xBB};
  ASSERT_EQ(ErrorOf(one), "");
  struct Case {
    std::string what;
    std::vector<uint8_t> bytes;
    std::string reason;  // a part of the expected message
  };
  const std::vector<Case> cases = {
      {"empty", {}, "truncated header"},
      {"short header", {2, 0, 0, 0}, "truncated header"},
      {"version 1", {1, 0, 0, 0, 0}, "version"},
      {"version 3", {3, 0, 0, 0, 0}, "version"},
      {"op code 1", {2, 1, 0, 0, 0}, "op code"},
      {"op code 2", {2, 2, 0, 0, 0}, "op code"},
      {"no frames but one announced", {2, 0, 0, 0, 1}, "count"},
      {"fewer frames than announced", {2, 0, 0, 0, 2, 0, 0, 1, 0x23, 2, 0xAA, 0xBB}, ""},
      {"many announced", {2, 0, 0, 0xFF, 0xFF, 0, 0, 1, 0x23, 0}, "count"},
      {"trailing byte", {2, 0, 0, 0, 1, 0, 0, 1, 0x23, 2, 0xAA, 0xBB, 0}, "trailing"},
      {"frame but count 0", {2, 0, 0, 0, 0, 0, 0, 1, 0x23, 0}, "trailing"},
      {"truncated data", {2, 0, 0, 0, 1, 0, 0, 1, 0x23, 3, 0xAA, 0xBB}, "truncated"},
      {"truncated FD flags", {2, 0, 0, 0, 1, 0, 0, 1, 0x23, 0x80}, "truncated"},
      {"truncated FD data", {2, 0, 0, 0, 1, 0, 0, 1, 0x23, 0x81, 0}, "truncated"},
      {"classic length 9", {2, 0, 0, 0, 1, 0, 0, 1, 0x23, 9, 1, 2, 3, 4, 5, 6, 7, 8, 9}, "> 8"},
      {"remote length 9", {2, 0, 0, 0, 1, 0x40, 0, 1, 0x23, 9}, "> 8"},
      {"length 0x7F", {2, 0, 0, 0, 1, 0, 0, 1, 0x23, 0x7F}, "> 8"},
      {"FD length 9", {2, 0, 0, 0, 1, 0, 0, 1, 0x23, 0x89, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9}, "FD"},
      {"FD length 65", {2, 0, 0, 0, 1, 0, 0, 1, 0x23, 0xC1, 0}, "FD length"},
      {"remote FD", {2, 0, 0, 0, 1, 0x40, 0, 1, 0x23, 0x81, 0, 1}, "remote"},
      {"error frame", {2, 0, 0, 0, 1, 0x20, 0, 0, 0x04, 8, 0, 4, 0, 0, 0, 0, 0, 0}, "error"},
      {"extended error frame", {2, 0, 0, 0, 1, 0xA0, 0, 0, 0x04, 0}, "error"},
      {"standard id > 0x7FF", {2, 0, 0, 0, 1, 0, 0, 0x08, 0x00, 0}, "id"},
  };
  for (const auto& c : cases) {
    const std::string error = ErrorOf(c.bytes);
    EXPECT_FALSE(error.empty()) << c.what;
    EXPECT_NE(error.find(c.reason), std::string::npos) << c.what << ": " << error;
    EXPECT_EQ(error.find('\n'), std::string::npos) << c.what;
  }
}

TEST(CannelloniTest, EveryProperPrefixIsRejected) {
  const std::vector<CanFrame> frames = {Frame(0x102, {1, 2, 3}), Remote(0x1F, 2, true),
                                        Frame(0x5, std::vector<uint8_t>(64, 0x55), false, true)};
  const auto bytes = EncodeCannelloni(9, frames);
  for (size_t n = 0; n < bytes.size(); ++n) {
    const std::vector<uint8_t> prefix(bytes.begin(), bytes.begin() + static_cast<long>(n));
    EXPECT_NE(ErrorOf(prefix), "") << n;
  }
  EXPECT_EQ(ErrorOf(bytes), "");
}

SequenceCounters Track(const std::vector<int>& sequence) {
  SequenceTracker tracker;
  for (const int s : sequence) tracker.Observe(static_cast<uint8_t>(s));
  return tracker.counters();
}

TEST(SequenceTrackerTest, InOrderIncludingWrapAround) {
  std::vector<int> sequence;
  for (int i = 200; i < 200 + 600; ++i) sequence.push_back(i % 256);
  const auto c = Track(sequence);
  EXPECT_EQ(c.datagrams, 600u);
  EXPECT_EQ(c.lost, 0u);
  EXPECT_EQ(c.reordered, 0u);
}

TEST(SequenceTrackerTest, FirstNumberIsArbitrary) {
  const auto c = Track({77, 78});
  EXPECT_EQ(c.datagrams, 2u);
  EXPECT_EQ(c.lost, 0u);
  EXPECT_EQ(c.reordered, 0u);
}

TEST(SequenceTrackerTest, CountsLoss) {
  auto c = Track({1, 2, 5, 6});
  EXPECT_EQ(c.lost, 2u);
  EXPECT_EQ(c.reordered, 0u);
  c = Track({250, 251, 3, 4});  // across the wrap: 252..255, 0..2 lost
  EXPECT_EQ(c.lost, 7u);
  EXPECT_EQ(c.reordered, 0u);
  c = Track({0, 127});  // the largest jump forward: 126 lost
  EXPECT_EQ(c.lost, 126u);
  EXPECT_EQ(c.reordered, 0u);
}

TEST(SequenceTrackerTest, CountsReorderingAndDuplicates) {
  auto c = Track({1, 2, 4, 3, 5});  // 3 is late: counted lost when 4 came, then reordered
  EXPECT_EQ(c.datagrams, 5u);
  EXPECT_EQ(c.lost, 1u);
  EXPECT_EQ(c.reordered, 1u);
  c = Track({1, 2, 2, 3, 3, 3});
  EXPECT_EQ(c.lost, 0u);
  EXPECT_EQ(c.reordered, 3u);
  c = Track({0, 128, 1});  // 128 is 128 behind-or-ahead: late; the stream goes on at 1
  EXPECT_EQ(c.lost, 0u);
  EXPECT_EQ(c.reordered, 1u);
  c = Track({255, 0, 255, 1});  // a late 255 after the wrap
  EXPECT_EQ(c.lost, 0u);
  EXPECT_EQ(c.reordered, 1u);
  c = Track({10, 5, 11});  // a datagram from before the first one
  EXPECT_EQ(c.lost, 0u);
  EXPECT_EQ(c.reordered, 1u);
}

}  // namespace
}  // namespace slam::hw
