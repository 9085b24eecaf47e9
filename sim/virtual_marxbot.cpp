#include "sim/virtual_marxbot.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <thread>

#include "engine/thread_safety.hpp"
#include "hw_link/aseba.hpp"
#include "hw_link/event_decoder.hpp"

namespace slam::sim {
namespace {

constexpr double kStuffingFactor = 1.1;    // typical bit stuffing on this traffic
constexpr double kFrameOverheadBits = 47;  // standard frame without data, with inter-frame space
constexpr double kUnpacedChunkS = 0.2;     // simulated time per Read when not paced

std::vector<hw::CanFrame> Frames(const hw::AsebaMessage& m) {
  return hw::FragmentAseba(m.source, m.type, m.payload);
}

/// Hands a simulation's readings to the bus in time order (odometry first at equal times).
void SendReadings(const RobotDescription& robot, const ScenarioOutput& output, CanBusModel& bus,
                  uint64_t* events) {
  for (const RobotEvent& event : MergeEvents(output.odometry, output.scanner)) {
    const hw::AsebaMessage message =
        std::holds_alternative<OdometryReading>(event)
            ? hw::EncodeOdometry(robot, std::get<OdometryReading>(event))
            : hw::EncodeScanner(robot, std::get<ScannerReading>(event));
    bus.Send(Frames(message), message.t);
    if (events != nullptr) ++*events;
  }
}

}  // namespace

void CanBusModel::Send(const std::vector<hw::CanFrame>& frames, double t) {
  for (const hw::CanFrame& frame : frames) nodes_[frame.id & 0xFF].push_back({t, frame});
}

double CanBusModel::FrameSeconds(const hw::CanFrame& frame) const {
  return std::round(kStuffingFactor * (kFrameOverheadBits + 8.0 * frame.len)) / bitrate_bps_;
}

size_t CanBusModel::pending() const {
  size_t n = 0;
  for (const auto& [node, queue] : nodes_) n += queue.size();
  return n;
}

void CanBusModel::Deliver(double until, std::vector<std::pair<double, hw::CanFrame>>& out) {
  for (;;) {
    // The earliest time any head frame is ready.
    double earliest = std::numeric_limits<double>::infinity();
    for (const auto& [node, queue] : nodes_) {
      if (!queue.empty()) earliest = std::min(earliest, queue.front().ready_t);
    }
    if (!std::isfinite(earliest)) return;
    const double start = std::max(bus_t_, earliest);
    if (!(start < until)) return;
    // Arbitration among the frames ready at `start`: the lowest id wins.
    std::deque<Queued>* winner = nullptr;
    for (auto& [node, queue] : nodes_) {
      if (queue.empty() || queue.front().ready_t > start) continue;
      if (winner == nullptr || queue.front().frame.id < winner->front().frame.id) winner = &queue;
    }
    const hw::CanFrame frame = winner->front().frame;
    winner->pop_front();
    bus_t_ = start + FrameSeconds(frame);
    out.emplace_back(bus_t_, frame);
  }
}

std::vector<std::pair<double, hw::CanFrame>> SimulatedFrames(const RobotDescription& robot,
                                                             const ScenarioOutput& output) {
  CanBusModel bus;
  SendReadings(robot, output, bus, nullptr);
  std::vector<std::pair<double, hw::CanFrame>> frames;
  bus.Deliver(std::numeric_limits<double>::max(), frames);
  return frames;
}

VirtualMarxbotSource::VirtualMarxbotSource(const World& world, std::string world_name,
                                           const RobotDescription& robot,
                                           const ScenarioConfig& config,
                                           const VirtualMarxbotOptions& options)
    : world_name_(std::move(world_name)),
      odometry_profile_(config.odometry.profile),
      robot_(robot),
      options_(options),
      simulator_(world, robot, config),
      world_(world),
      robot_radius_m_(config.robot_radius_m) {
  MutexLock lock(kidnap_mutex_);
  RememberPose(simulator_.time(), simulator_.pose());
  next_remembered_t_ = simulator_.time() + kRememberedPoseS;
}

void VirtualMarxbotSource::RememberPose(double t, const Pose2& pose) {
  if (!remembered_.empty() && t < remembered_.back().t + remembered_spacing_s_) return;
  remembered_.push_back({t, pose});
  if (remembered_.size() < kRememberedPoses) return;
  // Every other pose, the first and the newest kept.
  size_t kept = 0;
  for (size_t i = 0; i < remembered_.size(); i += 2) remembered_[kept++] = remembered_[i];
  if (remembered_.size() % 2 == 0) remembered_[kept++] = remembered_.back();
  remembered_.resize(kept);
  remembered_spacing_s_ *= 2.0;
}

Result<Pose2> VirtualMarxbotSource::Kidnap(std::optional<Pose2> target) {
  MutexLock lock(kidnap_mutex_);
  if (target) {
    if (Result<void> free = CheckFreePose(world_, robot_radius_m_, *target); !free.ok())
      return Error("cannot set the robot down there: " + free.Message());
    target->theta = NormalizeAngle(target->theta);
  } else {
    // The remembered pose nearest half the run ago (a place the robot stood on, so free).
    const double half = simulated_s_ / 2.0;
    const auto nearest = std::min_element(remembered_.begin(), remembered_.end(),
                                          [&](const TimedPose& a, const TimedPose& b) {
                                            return std::abs(a.t - half) < std::abs(b.t - half);
                                          });
    target = nearest->pose;
  }
  requested_kidnap_ = target;
  return *target;
}

uint64_t VirtualMarxbotSource::kidnaps() const {
  MutexLock lock(kidnap_mutex_);
  return kidnaps_;
}

void VirtualMarxbotSource::Advance(double until_s) {
  ScenarioOutput output;
  {
    MutexLock lock(kidnap_mutex_);
    if (requested_kidnap_) {
      // Checked when requested; the world does not change.
      (void)simulator_.Kidnap(*requested_kidnap_);
      requested_kidnap_.reset();
    }
  }
  std::vector<TimedPose> to_remember;
  while (simulator_.time() <= until_s) {
    if (simulator_.time() >= next_remembered_t_) {
      to_remember.push_back({simulator_.time(), simulator_.pose()});
      next_remembered_t_ += kRememberedPoseS;
    }
    simulator_.Step(output);
  }
  {
    MutexLock lock(kidnap_mutex_);
    for (const TimedPose& p : to_remember) RememberPose(p.t, p.pose);
    kidnaps_ += output.kidnaps.size();
    simulated_s_ = simulator_.time();
  }
  SendReadings(robot_, output, bus_, &events_);
  std::vector<std::pair<double, hw::CanFrame>> delivered;
  // Readings made so far are at times before simulator_.time(): everything starting before it
  // has been arbitrated against every frame that could compete.
  bus_.Deliver(simulator_.time(), delivered);
  ready_.insert(ready_.end(), delivered.begin(), delivered.end());
  if (!output.ground_truth.empty()) {
    MutexLock lock(truth_mutex_);
    ground_truth_.insert(ground_truth_.end(), output.ground_truth.begin(),
                         output.ground_truth.end());
    const double keep_from = ground_truth_.back().t - kKeptTruthS;
    while (ground_truth_.front().t < keep_from) {
      ground_truth_.pop_front();
      ++truth_dropped_;
    }
  }
}

hw::ReadOutcome VirtualMarxbotSource::Read(std::vector<hw::TimedFrame>& out,
                                           std::chrono::milliseconds timeout) {
  const int64_t now = hw::SteadyNowNs();
  if (!started_) {
    started_ = true;
    start_ns_ = now;
  }
  const bool bounded = options_.duration_s > 0.0;
  double target = 0.0;
  if (options_.paced) {
    target = static_cast<double>(now - start_ns_) * 1e-9 * options_.speed;
    const double horizon = target + static_cast<double>(timeout.count()) * 1e-3 * options_.speed;
    if (ready_.empty() || ready_.front().first > target) Advance(horizon);
    if (ready_.empty() || ready_.front().first > target) {
      // Nothing due yet: wait for the next frame, at most the timeout.
      double next_due = ready_.empty() ? horizon : std::min(ready_.front().first, horizon);
      if (bounded) next_due = std::min(next_due, std::max(target, options_.duration_s));
      std::this_thread::sleep_for(
          std::chrono::duration<double>((next_due - target) / options_.speed));
      target = next_due;
    }
  } else {
    target = simulator_.time() + kUnpacedChunkS;
    Advance(target);
  }
  if (bounded) target = std::min(target, options_.duration_s);
  const int64_t receive_ns = hw::SteadyNowNs();
  while (!ready_.empty() && ready_.front().first <= target &&
         !(bounded && ready_.front().first > options_.duration_s)) {
    hw::TimedFrame frame;
    frame.frame = ready_.front().second;
    frame.t = ready_.front().first;
    frame.source_t = frame.t;
    frame.receive_ns = receive_ns;
    out.push_back(frame);
    ready_.pop_front();
    ++frames_;
  }
  if (bounded && (ready_.empty() || ready_.front().first > options_.duration_s) &&
      simulator_.time() > options_.duration_s) {
    return {hw::ReadStatus::kEnd, "the simulated run reached its duration"};
  }
  return {};
}

std::string VirtualMarxbotSource::Describe() const { return "sim:" + world_name_; }

hw::SourceCounters VirtualMarxbotSource::Counters() const {
  return {{"events", events_}, {"frames", frames_}, {"bus_backlog", bus_.pending()}};
}

std::vector<TimedPose> VirtualMarxbotSource::GroundTruth() const {
  MutexLock lock(truth_mutex_);
  return {ground_truth_.begin(), ground_truth_.end()};
}

size_t VirtualMarxbotSource::GroundTruthSince(size_t first, std::vector<TimedPose>& out) const {
  MutexLock lock(truth_mutex_);
  const size_t made = truth_dropped_ + ground_truth_.size();
  const size_t from = std::max(first, truth_dropped_) - truth_dropped_;
  if (from < ground_truth_.size()) {
    out.insert(out.end(), ground_truth_.begin() + static_cast<std::ptrdiff_t>(from),
               ground_truth_.end());
  }
  return made;
}

}  // namespace slam::sim
