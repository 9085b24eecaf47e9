// The link thread and its event queue: decoded events arrive in order, anomalies are counted,
// source errors are survived, a slow consumer never blocks the link, and stopping is clean.

#include "hw_link/link.hpp"

#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <thread>
#include <variant>
#include <vector>

#include "hw_link/aseba.hpp"
#include "hw_link/candump.hpp"
#include "hw_link/event_decoder.hpp"
#include "hw_link/transports.hpp"
#include "test_support.hpp"

namespace slam::hw {
namespace {

using std::chrono::milliseconds;

// A scripted source: hands out its frames a batch per Read, fails on chosen reads, then ends
// (or, when `endless`, keeps timing out). Sets *destroyed when destroyed.
class FakeSource final : public FrameSource {
 public:
  struct Script {
    std::vector<TimedFrame> frames;
    size_t batch = 8;
    std::vector<int> failing_reads;  // 0-based Read calls that return kError
    bool endless = false;
    std::shared_ptr<std::atomic<bool>> destroyed;
  };

  explicit FakeSource(Script script) : script_(std::move(script)) {}
  ~FakeSource() override {
    if (script_.destroyed) script_.destroyed->store(true);
  }

  ReadOutcome Read(std::vector<TimedFrame>& out, milliseconds timeout) override {
    const int call = reads_++;
    for (int failing : script_.failing_reads) {
      if (failing == call) return {ReadStatus::kError, "device gone"};
    }
    if (next_ == script_.frames.size()) {
      if (!script_.endless) return {ReadStatus::kEnd, {}};
      std::this_thread::sleep_for(timeout);
      return {};
    }
    const size_t end = std::min(script_.frames.size(), next_ + script_.batch);
    out.insert(out.end(), script_.frames.begin() + static_cast<std::ptrdiff_t>(next_),
               script_.frames.begin() + static_cast<std::ptrdiff_t>(end));
    next_ = end;
    return {};
  }

  std::string Describe() const override { return "fake"; }
  SourceCounters Counters() const override { return {{"reads", static_cast<uint64_t>(reads_)}}; }

 private:
  Script script_;
  size_t next_ = 0;
  int reads_ = 0;
};

// Events and the frames that carry them (each frame of a message stamped with the event's time,
// receive_ns = 1000 + the event's index).
struct Traffic {
  std::vector<RobotEvent> events;
  std::vector<TimedFrame> frames;
  std::vector<int64_t> receive_ns;
};

void AddMessage(Traffic& traffic, const AsebaMessage& message, int64_t receive_ns) {
  for (const CanFrame& frame : FragmentAseba(message.source, message.type, message.payload)) {
    TimedFrame timed;
    timed.frame = frame;
    timed.t = message.t;
    timed.receive_ns = receive_ns;
    traffic.frames.push_back(timed);
  }
}

Traffic MakeTraffic(const RobotDescription& robot, int count, bool with_anomalies) {
  Traffic traffic;
  for (int i = 0; i < count; ++i) {
    const double t = 100.0 + 0.01 * i;
    const int64_t receive_ns = 1000 + i;
    if (i % 2 == 0) {
      OdometryReading odometry;
      odometry.t = t;
      odometry.seq = static_cast<uint16_t>(i);
      odometry.left_ticks =  // wraps
          static_cast<int32_t>(2'147'483'000u + 100u * static_cast<uint32_t>(i));
      odometry.right_ticks = -50 * i;
      odometry.gyro_raw = static_cast<int16_t>(i - 20);
      traffic.events.emplace_back(odometry);
      AddMessage(traffic, EncodeOdometry(robot, odometry), receive_ns);
    } else {
      ScannerReading scanner;
      scanner.t = t;
      scanner.seq = static_cast<uint16_t>(i);
      scanner.angle_raw = static_cast<uint16_t>(997 * i);
      scanner.raw = {static_cast<uint16_t>(i), 1023, 0, 512};
      scanner.rectifier_mv = static_cast<uint16_t>(6000 + i);
      traffic.events.emplace_back(scanner);
      AddMessage(traffic, EncodeScanner(robot, scanner), receive_ns);
    }
    traffic.receive_ns.push_back(receive_ns);
    if (with_anomalies && i == count / 2) {
      // A message from a node that is neither the base nor the scanner, and an extended frame.
      AsebaMessage stranger;
      stranger.source = 9;
      stranger.type = 0x10;
      stranger.payload = {1, 2, 3, 4};
      stranger.t = t;
      AddMessage(traffic, stranger, receive_ns);
      TimedFrame extended;
      extended.frame.id = 0x102;
      extended.frame.extended = true;
      extended.frame.len = 8;
      extended.t = t;
      traffic.frames.push_back(extended);
    }
  }
  return traffic;
}

std::unique_ptr<FrameSource> MakeFake(const Traffic& traffic, size_t batch = 8) {
  FakeSource::Script script;
  script.frames = traffic.frames;
  script.batch = batch;
  return std::make_unique<FakeSource>(std::move(script));
}

// Pops events until the link is drained (or 5 s pass).
std::vector<LinkEvent> PopAll(Link& link) {
  std::vector<LinkEvent> events;
  const auto give_up = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (!link.Drained() && std::chrono::steady_clock::now() < give_up) {
    LinkEvent event;
    if (link.PopWait(event, milliseconds(20))) events.push_back(event);
  }
  EXPECT_TRUE(link.Drained()) << "state " << ToString(link.Status().state);
  return events;
}

// Waits until `predicate` holds (or 5 s pass); whether it held.
template <typename Predicate>
bool WaitFor(Predicate predicate) {
  const auto give_up = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (!predicate()) {
    if (std::chrono::steady_clock::now() >= give_up) return false;
    std::this_thread::sleep_for(milliseconds(1));
  }
  return true;
}

LinkOptions FastOptions() {
  LinkOptions options;
  options.read_timeout = milliseconds(5);
  options.error_retry = milliseconds(5);
  return options;
}

// --------------------------------------------------------------------------------------------
// EventQueue

LinkEvent EventNumber(int i) {
  OdometryReading reading;
  reading.seq = static_cast<uint16_t>(i);
  reading.left_ticks = i;
  return LinkEvent{reading, i};
}

TEST(EventQueueTest, HoldsUpToItsCapacityInOrder) {
  EventQueue queue(4);
  EXPECT_EQ(queue.capacity(), 4u);
  LinkEvent event;
  EXPECT_FALSE(queue.TryPop(event));
  for (int i = 0; i < 4; ++i) EXPECT_TRUE(queue.TryPush(EventNumber(i)));
  EXPECT_FALSE(queue.TryPush(EventNumber(4)));
  EXPECT_EQ(queue.size(), 4u);
  for (int round = 0; round < 10; ++round) {  // wrap around the ring a few times
    ASSERT_TRUE(queue.TryPop(event));
    EXPECT_EQ(event.receive_ns, round);
    EXPECT_TRUE(queue.TryPush(EventNumber(round + 4)));
    EXPECT_EQ(queue.size(), 4u);
  }
  for (int i = 10; i < 14; ++i) {
    ASSERT_TRUE(queue.TryPop(event));
    EXPECT_EQ(event.receive_ns, i);
  }
  EXPECT_FALSE(queue.TryPop(event));
  EXPECT_EQ(queue.size(), 0u);
  EXPECT_EQ(EventQueue(0).capacity(), 1u);
}

TEST(EventQueueTest, PopWaitTimesOutWhenEmptyAndWakesOnPush) {
  EventQueue queue(8);
  LinkEvent event;
  const auto start = std::chrono::steady_clock::now();
  EXPECT_FALSE(queue.PopWait(event, milliseconds(20)));
  EXPECT_GE(std::chrono::steady_clock::now() - start, milliseconds(19));

  std::thread producer([&] {
    std::this_thread::sleep_for(milliseconds(20));
    queue.TryPush(EventNumber(7));
  });
  const auto wait_start = std::chrono::steady_clock::now();
  EXPECT_TRUE(queue.PopWait(event, milliseconds(3000)));
  EXPECT_LT(std::chrono::steady_clock::now() - wait_start, milliseconds(1500));
  EXPECT_EQ(event.receive_ns, 7);
  producer.join();
}

TEST(EventQueueTest, SingleProducerSingleConsumerKeepsOrderAndLosesNothing) {
  constexpr int kEvents = 100'000;
  EventQueue queue(64);
  std::atomic<size_t> max_size{0};
  std::thread producer([&] {
    for (int i = 0; i < kEvents; ++i) {
      while (!queue.TryPush(EventNumber(i))) std::this_thread::yield();
    }
  });
  int expected = 0;
  bool in_order = true;
  const auto give_up = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  while (expected < kEvents && std::chrono::steady_clock::now() < give_up) {
    max_size = std::max(max_size.load(), queue.size());
    LinkEvent event;
    if (!queue.PopWait(event, milliseconds(10))) continue;
    const auto& reading = std::get<OdometryReading>(event.event);
    in_order = in_order && event.receive_ns == expected && reading.left_ticks == expected;
    ++expected;
  }
  producer.join();
  EXPECT_EQ(expected, kEvents);
  EXPECT_TRUE(in_order);
  EXPECT_LE(max_size.load(), 64u);
  EXPECT_EQ(queue.size(), 0u);
}

// --------------------------------------------------------------------------------------------
// Link

TEST(LinkTest, StateNames) {
  EXPECT_STREQ(ToString(LinkState::kIdle), "idle");
  EXPECT_STREQ(ToString(LinkState::kRunning), "running");
  EXPECT_STREQ(ToString(LinkState::kSourceError), "source_error");
  EXPECT_STREQ(ToString(LinkState::kEnded), "ended");
  EXPECT_STREQ(ToString(LinkState::kStopped), "stopped");
}

TEST(LinkTest, DeliversDecodedEventsInOrderAndCountsAnomalies) {
  const RobotDescription robot = testing::ShippedRobot();
  const Traffic traffic = MakeTraffic(robot, 200, /*with_anomalies=*/true);
  Link link(MakeFake(traffic, 7), robot, FastOptions());
  EXPECT_EQ(link.Status().state, LinkState::kIdle);
  EXPECT_EQ(link.Status().source, "fake");
  link.Start();

  const std::vector<LinkEvent> events = PopAll(link);
  ASSERT_EQ(events.size(), traffic.events.size());
  for (size_t i = 0; i < events.size(); ++i) {
    EXPECT_EQ(events[i].event, traffic.events[i]) << i;
    EXPECT_EQ(events[i].receive_ns, traffic.receive_ns[i]) << i;
  }
  const LinkStatus status = link.Status();
  EXPECT_EQ(status.state, LinkState::kEnded);
  EXPECT_EQ(status.frames, traffic.frames.size());
  EXPECT_EQ(status.reassembly.frames, traffic.frames.size());
  EXPECT_EQ(status.reassembly.extended, 1u);
  EXPECT_EQ(status.reassembly.Rejected(), 1u);
  EXPECT_EQ(status.reassembly.messages, traffic.events.size() + 1);
  EXPECT_EQ(status.decoder.unknown_node, 1u);
  EXPECT_EQ(status.decoder.odometry, 100u);
  EXPECT_EQ(status.decoder.scanner, 100u);
  EXPECT_EQ(status.events_queued, traffic.events.size());
  EXPECT_EQ(status.queue_drops, 0u);
  EXPECT_EQ(status.queue_size, 0u);
  EXPECT_EQ(status.source_errors, 0u);
  EXPECT_TRUE(status.last_error.empty());
  ASSERT_EQ(status.source_counters.size(), 1u);
  EXPECT_EQ(status.source_counters[0].first, "reads");

  link.Stop();
  EXPECT_EQ(link.Status().state, LinkState::kEnded);  // ended stays ended
  link.Stop();                                        // idempotent
}

TEST(LinkTest, SurvivesSourceErrorsAndKeepsReading) {
  const RobotDescription robot = testing::ShippedRobot();
  const Traffic traffic = MakeTraffic(robot, 40, /*with_anomalies=*/false);
  FakeSource::Script script;
  script.frames = traffic.frames;
  script.batch = 5;
  script.failing_reads = {2, 3, 6};
  Link link(std::make_unique<FakeSource>(std::move(script)), robot, FastOptions());
  link.Start();
  const std::vector<LinkEvent> events = PopAll(link);
  ASSERT_EQ(events.size(), traffic.events.size());
  for (size_t i = 0; i < events.size(); ++i) EXPECT_EQ(events[i].event, traffic.events[i]) << i;
  const LinkStatus status = link.Status();
  EXPECT_EQ(status.state, LinkState::kEnded);
  EXPECT_EQ(status.source_errors, 3u);
  EXPECT_EQ(status.last_error, "device gone");
}

TEST(LinkTest, ReportsTheSourceErrorStateAndStopsPromptlyDuringTheRetryPause) {
  const RobotDescription robot = testing::ShippedRobot();
  FakeSource::Script script;
  script.failing_reads = {0};
  script.endless = true;
  LinkOptions options;
  options.read_timeout = milliseconds(5);
  options.error_retry = std::chrono::seconds(30);
  Link link(std::make_unique<FakeSource>(std::move(script)), robot, options);
  link.Start();
  EXPECT_TRUE(WaitFor([&] { return link.Status().state == LinkState::kSourceError; }));
  const auto start = std::chrono::steady_clock::now();
  link.Stop();
  EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(2));
  const LinkStatus status = link.Status();
  EXPECT_EQ(status.state, LinkState::kStopped);
  EXPECT_EQ(status.source_errors, 1u);
  EXPECT_EQ(status.last_error, "device gone");
}

TEST(LinkTest, StopsARunningLinkAndTheDestructorJoins) {
  const RobotDescription robot = testing::ShippedRobot();
  {
    FakeSource::Script script;
    script.endless = true;
    Link link(std::make_unique<FakeSource>(std::move(script)), robot, FastOptions());
    link.Start();
    EXPECT_EQ(link.Status().state, LinkState::kRunning);
    EXPECT_TRUE(WaitFor([&] { return !link.Status().source_counters.empty(); }));
    link.Stop();
    EXPECT_EQ(link.Status().state, LinkState::kStopped);
    EXPECT_FALSE(link.Drained());
    link.Stop();
    EXPECT_EQ(link.Status().state, LinkState::kStopped);
  }
  auto destroyed = std::make_shared<std::atomic<bool>>(false);
  const auto start = std::chrono::steady_clock::now();
  {
    FakeSource::Script script;
    script.endless = true;
    script.destroyed = destroyed;
    Link link(std::make_unique<FakeSource>(std::move(script)), robot, FastOptions());
    link.Start();
    EXPECT_TRUE(WaitFor([&] { return !link.Status().source_counters.empty(); }));
    EXPECT_FALSE(destroyed->load());
  }  // no Stop(): the destructor stops and joins before the source goes
  EXPECT_TRUE(destroyed->load());
  EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(3));
  {
    Link never_started(MakeFake(Traffic{}), robot);  // destroyed without Start: fine
    EXPECT_EQ(never_started.Status().state, LinkState::kIdle);
  }
}

TEST(LinkTest, SlowConsumerMakesTheLinkDropNotBlock) {
  const RobotDescription robot = testing::ShippedRobot();
  constexpr int kEvents = 10'000;
  constexpr size_t kCapacity = 64;
  const Traffic traffic = MakeTraffic(robot, kEvents, /*with_anomalies=*/false);
  LinkOptions options = FastOptions();
  options.queue_capacity = kCapacity;
  Link link(MakeFake(traffic, 256), robot, options);
  link.Start();
  // The consumer pops nothing until the source has ended; the queue never grows beyond its
  // capacity meanwhile.
  size_t max_size = 0;
  const bool ended = WaitFor([&] {
    const LinkStatus status = link.Status();
    max_size = std::max<size_t>(max_size, status.queue_size);
    return status.state == LinkState::kEnded;
  });
  ASSERT_TRUE(ended) << "the link blocked on a full queue";
  const LinkStatus status = link.Status();
  EXPECT_LE(max_size, kCapacity);
  EXPECT_EQ(status.queue_size, kCapacity);
  EXPECT_EQ(status.events_queued, kCapacity);
  EXPECT_EQ(status.queue_drops, static_cast<uint64_t>(kEvents) - kCapacity);
  EXPECT_EQ(status.decoder.odometry + status.decoder.scanner, static_cast<uint64_t>(kEvents));
  EXPECT_FALSE(link.Drained());
  // What was kept are the oldest events.
  for (size_t i = 0; i < kCapacity; ++i) {
    LinkEvent event;
    ASSERT_TRUE(link.Pop(event));
    EXPECT_EQ(event.event, traffic.events[i]) << i;
  }
  LinkEvent none;
  EXPECT_FALSE(link.Pop(none));
  EXPECT_TRUE(link.Drained());
}

TEST(LinkTest, EndToEndFromACandumpReplay) {
  const RobotDescription robot = testing::ShippedRobot();
  const Traffic traffic = MakeTraffic(robot, 60, /*with_anomalies=*/true);
  const std::filesystem::path path =
      std::filesystem::temp_directory_path() /
      ("link_test_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) + "_" +
       std::to_string(SteadyNowNs()) + ".log");
  {
    std::ofstream file(path);
    file << "# candump -l\n";
    for (const TimedFrame& frame : traffic.frames) {
      file << FormatCandumpLine(static_cast<int64_t>(std::llround(frame.t * 1e6)), "can0",
                                frame.frame)
           << "\n";
    }
    file << "garbage(\n(1.0) can0\n";
  }
  OpenResult opened = OpenCandumpReplay(path.string());
  std::filesystem::remove(path);  // the replay keeps its descriptor
  ASSERT_TRUE(opened.ok()) << opened.Message();
  Link link(std::move(opened).value(), robot, FastOptions());
  link.Start();
  const std::vector<LinkEvent> events = PopAll(link);
  ASSERT_EQ(events.size(), traffic.events.size());
  for (size_t i = 0; i < events.size(); ++i) {
    // The log keeps microseconds: times agree to that, everything else exactly.
    EXPECT_NEAR(EventTime(events[i].event), EventTime(traffic.events[i]), 1e-6) << i;
    RobotEvent expected = traffic.events[i];
    std::visit([&](auto& reading) { reading.t = EventTime(events[i].event); }, expected);
    EXPECT_EQ(events[i].event, expected) << i;
  }
  const LinkStatus status = link.Status();
  EXPECT_EQ(status.state, LinkState::kEnded);
  EXPECT_EQ(status.reassembly.extended, 1u);
  EXPECT_EQ(status.decoder.unknown_node, 1u);
  EXPECT_EQ(status.frames, traffic.frames.size());
  bool saw_bad_lines = false;
  for (const auto& [name, value] : status.source_counters) {
    if (name == "bad_lines") {
      saw_bad_lines = true;
      EXPECT_EQ(value, 1u);  // "(1.0) can0": "garbage(" is ignored like canplayer does
    }
  }
  EXPECT_TRUE(saw_bad_lines);
  EXPECT_NE(status.source.find("candump:"), std::string::npos);
}

}  // namespace
}  // namespace slam::hw
