// Link benchmarks: the marXbot's own frames (60 s of the rooms run through the Aseba fragmenter
// and the CAN bus model, both nodes interleaved as on the robot) through Aseba fragmenting,
// reassembly, event decoding, and the candump and slcan parsers. Items are frames.
#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "bench/bench_support.hpp"
#include "hw_link/aseba.hpp"
#include "hw_link/can_frame.hpp"
#include "hw_link/candump.hpp"
#include "hw_link/event_decoder.hpp"
#include "hw_link/frame_decoder.hpp"
#include "hw_link/slcan.hpp"
#include "sim/experiment_writer.hpp"
#include "sim/virtual_marxbot.hpp"

namespace slam::bench {
namespace {

/// Every frame of 60 s of the rooms run, in bus order, with their times.
const std::vector<hw::TimedFrame>& Frames() {
  static const std::vector<hw::TimedFrame> frames = [] {
    std::vector<hw::TimedFrame> out;
    for (const auto& [t, frame] : sim::SimulatedFrames(ShippedRobot(), RoomsRun(60.0).output)) {
      hw::TimedFrame timed;
      timed.frame = frame;
      timed.t = t;
      out.push_back(timed);
    }
    return out;
  }();
  return frames;
}

/// The same frames as candump -l lines (without newlines).
const std::vector<std::string>& CandumpLines() {
  static const std::vector<std::string> lines = [] {
    std::vector<std::string> out;
    for (const hw::TimedFrame& f : Frames()) {
      const int64_t us = sim::kSimulationEpochUs + std::llround(f.t * 1e6);
      out.push_back(hw::FormatCandumpLine(us, sim::kSimulatedInterface, f.frame));
    }
    return out;
  }();
  return lines;
}

// Aseba messages of the run (odometry and scanner events) cut into frames. Items are frames.
void BM_AsebaFragment(benchmark::State& state) {
  const RobotDescription& robot = ShippedRobot();
  std::vector<hw::AsebaMessage> messages;
  for (const OdometryReading& r : RoomsRun(60.0).output.odometry)
    messages.push_back(hw::EncodeOdometry(robot, r));
  for (const ScannerReading& r : RoomsRun(60.0).output.scanner)
    messages.push_back(hw::EncodeScanner(robot, r));
  int64_t frames = 0;
  for (auto _ : state) {
    for (const hw::AsebaMessage& m : messages) {
      const std::vector<hw::CanFrame> cut = hw::FragmentAseba(m.source, m.type, m.payload);
      frames += static_cast<int64_t>(cut.size());
      benchmark::DoNotOptimize(cut.data());
    }
  }
  Items(state, frames, "frames");
}
BENCHMARK(BM_AsebaFragment);

// Aseba reassembly alone (per-source, interleaved nodes). Items are frames.
void BM_AsebaReassembly(benchmark::State& state) {
  const std::vector<hw::TimedFrame>& frames = Frames();
  for (auto _ : state) {
    hw::AsebaReassembler reassembler;
    for (const hw::TimedFrame& f : frames) benchmark::DoNotOptimize(reassembler.Push(f.frame, f.t));
    if (reassembler.counters().Rejected() != 0) state.SkipWithError("frames rejected");
  }
  Items(state, state.iterations() * static_cast<int64_t>(frames.size()), "frames");
}
BENCHMARK(BM_AsebaReassembly);

// Aseba frame decoding as the link thread does it: reassembly plus event decoding
// (hw::FrameDecoder). Items are frames.
void BM_AsebaDecode(benchmark::State& state) {
  const std::vector<hw::TimedFrame>& frames = Frames();
  for (auto _ : state) {
    hw::FrameDecoder decoder(ShippedRobot());
    for (const hw::TimedFrame& f : frames) benchmark::DoNotOptimize(decoder.Push(f));
    if (decoder.decoder().Rejected() != 0) state.SkipWithError("messages rejected");
  }
  Items(state, state.iterations() * static_cast<int64_t>(frames.size()), "frames");
}
BENCHMARK(BM_AsebaDecode);

// candump -l line parsing. Items are frames (lines); bytes/s counts the text.
void BM_CandumpParse(benchmark::State& state) {
  const std::vector<std::string>& lines = CandumpLines();
  int64_t bytes = 0;
  for (const std::string& line : lines) bytes += static_cast<int64_t>(line.size()) + 1;
  for (auto _ : state) {
    for (const std::string& line : lines) benchmark::DoNotOptimize(hw::ParseCandumpLine(line));
  }
  Items(state, state.iterations() * static_cast<int64_t>(lines.size()), "frames");
  state.SetBytesProcessed(state.iterations() * bytes);
}
BENCHMARK(BM_CandumpParse);

// A recorded log to robot events: candump parsing, reassembly and decoding. Items are frames.
void BM_CandumpToEvents(benchmark::State& state) {
  const std::vector<std::string>& lines = CandumpLines();
  for (auto _ : state) {
    hw::FrameDecoder decoder(ShippedRobot());
    for (const std::string& line : lines) {
      const hw::CandumpLine parsed = hw::ParseCandumpLine(line);
      hw::TimedFrame frame;
      frame.frame = parsed.frame;
      frame.t = static_cast<double>(parsed.time_us) * 1e-6;
      benchmark::DoNotOptimize(decoder.Push(frame));
    }
  }
  Items(state, state.iterations() * static_cast<int64_t>(lines.size()), "frames");
}
BENCHMARK(BM_CandumpToEvents);

// slcan stream parsing, the stream (with adapter time stamps) handed over in reads of range(0)
// bytes as a tty delivers it. Items are frames; bytes/s counts the stream.
void BM_SlcanParse(benchmark::State& state) {
  std::string stream;
  for (const hw::TimedFrame& f : Frames()) {
    stream +=
        hw::FormatSlcanFrame(f.frame, static_cast<uint16_t>(std::llround(f.t * 1000.0) % 60000));
  }
  const auto chunk = static_cast<size_t>(state.range(0));
  std::vector<hw::SlcanFrame> out;
  out.reserve(Frames().size());
  for (auto _ : state) {
    hw::SlcanParser parser;
    out.clear();
    for (size_t at = 0; at < stream.size(); at += chunk)
      parser.Feed(std::string_view(stream).substr(at, chunk), out);
    if (out.size() != Frames().size()) state.SkipWithError("frames lost");
    benchmark::DoNotOptimize(out.data());
  }
  Items(state, state.iterations() * static_cast<int64_t>(Frames().size()), "frames");
  state.SetBytesProcessed(state.iterations() * static_cast<int64_t>(stream.size()));
}
BENCHMARK(BM_SlcanParse)->ArgName("read_bytes")->Arg(64)->Arg(4096);

}  // namespace
}  // namespace slam::bench

BENCHMARK_MAIN();
