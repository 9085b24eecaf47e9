#include "hw_link/aseba.hpp"

#include <gtest/gtest.h>

#include <map>
#include <random>
#include <vector>

#include "can_test_support.hpp"

namespace slam::hw {
namespace {

using testing::Frame;
using testing::Remote;

// The worked example of docs/design.md appendix A: node 2, event 0x0020, words
// [1, 0x4000, 300, 512, 280, 490, 6500].
const std::vector<uint16_t> kExampleWords{1, 0x4000, 300, 512, 280, 490, 6500};

TEST(AsebaTest, WorkedExampleFragmentsByteForByte) {
  const std::vector<CanFrame> frames = FragmentAseba(2, 0x0020, WordsToBytes(kExampleWords));
  ASSERT_EQ(frames.size(), 2u);
  EXPECT_EQ(FormatCompact(frames[0]), "102#2000010000402C01");
  EXPECT_EQ(FormatCompact(frames[1]), "202#00021801EA016419");
}

TEST(AsebaTest, WorkedExampleReassembles) {
  AsebaReassembler r;
  EXPECT_FALSE(r.Push(Frame(0x102, {0x20, 0x00, 0x01, 0x00, 0x00, 0x40, 0x2C, 0x01}), 1.0));
  const auto m = r.Push(Frame(0x202, {0x00, 0x02, 0x18, 0x01, 0xEA, 0x01, 0x64, 0x19}), 2.0);
  ASSERT_TRUE(m);
  EXPECT_EQ(m->source, 2);
  EXPECT_EQ(m->type, 0x0020);
  EXPECT_EQ(m->payload, WordsToBytes(kExampleWords));
  EXPECT_EQ(m->t, 2.0);  // the time of the last frame
  EXPECT_EQ(r.counters().messages, 1u);
  EXPECT_EQ(r.counters().Rejected(), 0u);
}

TEST(AsebaTest, FrameCountsFollowTheSizeRules) {
  // type + payload <= 8 bytes: one single frame with DLC = size.
  for (size_t n = 0; n <= 6; ++n) {
    const auto frames = FragmentAseba(7, 0x1234, std::vector<uint8_t>(n, 0xAB));
    ASSERT_EQ(frames.size(), 1u) << n;
    EXPECT_EQ(frames[0].id, 0x307u);
    EXPECT_EQ(frames[0].len, 2 + n);
  }
  // 9 bytes: start (8) + stop (1); 16: start + stop (8); 17: start + middle + stop (1).
  EXPECT_EQ(FragmentAseba(1, 1, std::vector<uint8_t>(7)).size(), 2u);
  EXPECT_EQ(FragmentAseba(1, 1, std::vector<uint8_t>(14)).size(), 2u);
  const auto three = FragmentAseba(1, 1, std::vector<uint8_t>(15));
  ASSERT_EQ(three.size(), 3u);
  EXPECT_EQ(three[1].id, 0x001u);  // middle
  EXPECT_EQ(three[2].len, 1);
  // The largest message: 518 bytes = 65 frames.
  EXPECT_EQ(FragmentAseba(1, 1, std::vector<uint8_t>(kAsebaMaxMessageBytes - 2)).size(), 65u);
}

TEST(AsebaTest, InterleavedSendersReassembleExactly) {
  std::mt19937 rng(42);
  struct Sent {
    uint8_t source;
    uint16_t type;
    std::vector<uint8_t> payload;
  };
  const std::vector<uint8_t> sources{1, 2, 3, 17, 255};
  std::map<uint8_t, std::vector<Sent>> sent;
  std::map<uint8_t, std::vector<CanFrame>> pending;  // each sender's frames, in order
  for (int i = 0; i < 2000; ++i) {
    const uint8_t source = sources[rng() % sources.size()];
    Sent s{source, static_cast<uint16_t>(rng() & 0xFFFF), {}};
    const size_t n = (rng() % 8 == 0) ? rng() % (kAsebaMaxMessageBytes - 1) : rng() % 30;
    for (size_t k = 0; k < n; ++k) s.payload.push_back(static_cast<uint8_t>(rng()));
    for (const CanFrame& f : FragmentAseba(source, s.type, s.payload)) {
      pending[source].push_back(f);
    }
    sent[source].push_back(std::move(s));
  }
  // Interleave: repeatedly take the next frame of a random sender that still has frames.
  AsebaReassembler r;
  std::map<uint8_t, size_t> next;
  std::map<uint8_t, std::vector<AsebaMessage>> received;
  size_t remaining = 0;
  for (const auto& [source, frames] : pending) remaining += frames.size();
  const size_t total_frames = remaining;
  while (remaining > 0) {
    const uint8_t source = sources[rng() % sources.size()];
    if (next[source] == pending[source].size()) continue;
    if (auto m = r.Push(pending[source][next[source]++], 0.0)) {
      received[m->source].push_back(*m);
    }
    --remaining;
  }
  for (const auto& [source, messages] : sent) {
    ASSERT_EQ(received[source].size(), messages.size()) << int{source};
    for (size_t i = 0; i < messages.size(); ++i) {
      EXPECT_EQ(received[source][i].type, messages[i].type);
      EXPECT_EQ(received[source][i].payload, messages[i].payload);
    }
  }
  EXPECT_EQ(r.counters().frames, total_frames);
  EXPECT_EQ(r.counters().messages, 2000u);
  EXPECT_EQ(r.counters().Rejected(), 0u);
}

// Each anomaly is counted and the next, well-formed message still comes through.
class AsebaAnomalyTest : public ::testing::Test {
 protected:
  void ExpectNextMessageIntact() {
    const std::vector<uint8_t> payload{1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16};
    std::optional<AsebaMessage> m;
    for (const CanFrame& f : FragmentAseba(2, 0x20, payload)) m = r_.Push(f, 0.0);
    ASSERT_TRUE(m);
    EXPECT_EQ(m->payload, payload);
    EXPECT_EQ(m->type, 0x20);
  }
  AsebaReassembler r_;
  const std::vector<CanFrame> long_ = FragmentAseba(2, 0x20, std::vector<uint8_t>(20, 0x55));
};

TEST_F(AsebaAnomalyTest, MiddleWithoutStart) {
  r_.Push(long_[1], 0.0);  // middle
  EXPECT_EQ(r_.counters().middle_without_start, 1u);
  ExpectNextMessageIntact();
}

TEST_F(AsebaAnomalyTest, IdsWithBit10SetAreForeignNotAsebaFragments) {
  // Aseba's ids use bits 0..9 (fragment type, source). 0x6xx was read as a fragment of
  // source xx: another protocol's frames on the bus became starts and stops.
  CanFrame frame = long_[0];
  frame.id |= 0x400;
  r_.Push(frame, 0.0);
  for (CanFrame f : FragmentAseba(2, 0x20, std::vector<uint8_t>(4, 1))) {
    f.id |= 0x400;
    EXPECT_FALSE(r_.Push(f, 0.0));
  }
  EXPECT_EQ(r_.counters().foreign, 2u);
  EXPECT_EQ(r_.counters().messages, 0u);
  EXPECT_EQ(r_.counters().Rejected(), 2u);
  ExpectNextMessageIntact();
}

TEST_F(AsebaAnomalyTest, StopWithoutStart) {
  r_.Push(long_[2], 0.0);
  EXPECT_EQ(r_.counters().stop_without_start, 1u);
  ExpectNextMessageIntact();
}

TEST_F(AsebaAnomalyTest, WrongLengths) {
  CanFrame short_start = long_[0];
  short_start.len = 5;
  EXPECT_FALSE(r_.Push(short_start, 0.0));
  CanFrame single_one_byte = Frame(0x302, {0x20});
  EXPECT_FALSE(r_.Push(single_one_byte, 0.0));
  CanFrame empty_stop = long_[2];
  empty_stop.len = 0;
  r_.Push(long_[0], 0.0);
  EXPECT_FALSE(r_.Push(empty_stop, 0.0));  // abandons the message in progress
  EXPECT_FALSE(r_.Push(long_[2], 0.0));    // its real stop now has no start
  EXPECT_EQ(r_.counters().bad_length, 3u);
  EXPECT_EQ(r_.counters().abandoned, 1u);
  EXPECT_EQ(r_.counters().stop_without_start, 1u);
  ExpectNextMessageIntact();
}

TEST_F(AsebaAnomalyTest, OversizeMessageIsAbandoned) {
  r_.Push(long_[0], 0.0);
  for (int i = 0; i < 70; ++i) r_.Push(long_[1], 0.0);
  EXPECT_FALSE(r_.Push(long_[2], 0.0));
  EXPECT_EQ(r_.counters().oversize, 1u);
  EXPECT_GT(r_.counters().middle_without_start, 0u);  // the rest of the oversize message
  EXPECT_EQ(r_.counters().messages, 0u);
  ExpectNextMessageIntact();
}

TEST_F(AsebaAnomalyTest, ExtendedRemoteAndFdFramesAreDropped) {
  CanFrame extended = long_[0];
  extended.extended = true;
  CanFrame remote = long_[0];
  remote.remote = true;
  CanFrame fd = long_[0];
  fd.fd = true;
  fd.len = 12;
  r_.Push(long_[0], 0.0);  // a start in progress is not disturbed by foreign frames
  EXPECT_FALSE(r_.Push(extended, 0.0));
  EXPECT_FALSE(r_.Push(remote, 0.0));
  EXPECT_FALSE(r_.Push(fd, 0.0));
  EXPECT_FALSE(r_.Push(long_[1], 0.0));
  const auto m = r_.Push(long_[2], 0.0);
  ASSERT_TRUE(m);
  EXPECT_EQ(m->payload, std::vector<uint8_t>(20, 0x55));
  EXPECT_EQ(r_.counters().extended, 1u);
  EXPECT_EQ(r_.counters().remote, 1u);
  EXPECT_EQ(r_.counters().fd, 1u);
  ExpectNextMessageIntact();
}

TEST_F(AsebaAnomalyTest, SingleFrameInTheMiddleOfAMessage) {
  r_.Push(long_[0], 0.0);
  r_.Push(long_[1], 0.0);
  const auto single = r_.Push(FragmentAseba(2, 0x99, std::vector<uint8_t>{7, 0})[0], 0.0);
  ASSERT_TRUE(single);  // the single message is good; the interrupted one is lost
  EXPECT_EQ(single->type, 0x99);
  EXPECT_FALSE(r_.Push(long_[2], 0.0));
  EXPECT_EQ(r_.counters().abandoned, 1u);
  EXPECT_EQ(r_.counters().stop_without_start, 1u);
  ExpectNextMessageIntact();
}

TEST_F(AsebaAnomalyTest, AGapAbandonsMessagesInProgressInsteadOfGluingThem) {
  // Two-frame messages from two senders; the stop of the first message of sender 2 and the
  // start of its second are lost. Without the gap, its first start and second stop make one
  // message of the right size, of two messages' halves.
  const std::vector<uint8_t> a(12, 0xAA), b(12, 0xBB);
  const auto first = FragmentAseba(2, 0x20, a);
  const auto second = FragmentAseba(2, 0x20, b);
  const auto other = FragmentAseba(1, 0x10, a);
  ASSERT_EQ(first.size(), 2u);
  {
    AsebaReassembler glued;
    glued.Push(first[0], 0.0);
    const auto m = glued.Push(second[1], 0.0);
    ASSERT_TRUE(m);  // what happens without being told of the gap
    EXPECT_NE(m->payload, a);
    EXPECT_NE(m->payload, b);
  }
  r_.Push(first[0], 0.0);
  r_.Push(other[0], 0.0);
  r_.Gap();
  EXPECT_FALSE(r_.Push(second[1], 0.0));
  EXPECT_FALSE(r_.Push(other[1], 0.0));
  EXPECT_EQ(r_.counters().abandoned, 2u);  // both senders' messages in progress
  EXPECT_EQ(r_.counters().stop_without_start, 2u);
  r_.Gap();  // nothing in progress: nothing more abandoned
  EXPECT_EQ(r_.counters().abandoned, 2u);
  ExpectNextMessageIntact();
}

TEST_F(AsebaAnomalyTest, StartInTheMiddleOfAMessageRestarts) {
  r_.Push(long_[0], 0.0);
  EXPECT_EQ(r_.counters().abandoned, 0u);
  ExpectNextMessageIntact();  // its start frame abandons the first message
  EXPECT_EQ(r_.counters().abandoned, 1u);
}

TEST_F(AsebaAnomalyTest, AnomaliesOfOneSenderDoNotTouchAnother) {
  const auto other = FragmentAseba(9, 0x10, std::vector<uint8_t>(12, 0x11));
  r_.Push(other[0], 0.0);
  r_.Push(long_[1], 0.0);  // node 2 middle without start
  const auto m = r_.Push(other[1], 0.0);
  ASSERT_TRUE(m);
  EXPECT_EQ(m->source, 9);
  ExpectNextMessageIntact();
}

}  // namespace
}  // namespace slam::hw
