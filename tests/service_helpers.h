#ifndef IRRR_TESTS_SERVICE_HELPERS_H_
#define IRRR_TESTS_SERVICE_HELPERS_H_

// What the tests of the daemon's service share: sinks and producers that feed a Service
// in-process, hand-made keyframes and loops, the two-session Intel case with its undisturbed
// answer (RunIncrementalIrrr), a lossy link, and the service's logs turned off (the tests check
// the error channel instead).

#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <fmt/core.h>
#include <spdlog/spdlog.h>
#include <catch2/catch.hpp>
#include <lcm/lcm-cpp.hpp>

#include "clients/common/graph_files.h"
#include "clients/common/loop_csv.h"
#include "clients/common/replay_messages.h"
#include "core/irrr.h"
#include "daemon/common/irrr_config.h"
#include "daemon/journal.h"
#include "daemon/raw_subscription.h"
#include "daemon/sequencer.h"
#include "daemon/service.h"
#include "daemon/snapshot.h"
#include "daemon/stamp_merger.h"
#include "daemon/wire.h"
#include "irrr/correction_t.hpp"
#include "irrr/error_t.hpp"
#include "irrr/resync_request_t.hpp"
#include "irrr/solution_request_t.hpp"
#include "irrr/solution_t.hpp"
#include "irrr/verdicts_t.hpp"
#include "tests/recording_sink.h"
#include "tests/test_files.h"

namespace irrr {

// The service logs every rejection; the tests check the error channel instead.
inline const bool kQuietServiceLogs = [] {
  spdlog::set_level(spdlog::level::off);
  return true;
}();

// Publishes into one memq:// LCM instance (the only kind that sees its own messages).
class LcmSink : public MessageSink {
 public:
  explicit LcmSink(lcm::LCM* lcm) : lcm_(lcm) {}
  void Send(const std::string& channel, const std::vector<uint8_t>& bytes) override {
    REQUIRE(lcm_->publish(channel, bytes.data(), static_cast<unsigned>(bytes.size())) == 0);
  }

 private:
  lcm::LCM* lcm_;
};

struct ServiceReceiver {
  Service* service;
  std::map<std::string, int> heard;
  int step_corrections = 0;
  void OnMessage(const lcm::ReceiveBuffer* b, const std::string& channel) {
    ++heard[channel];
    correction_t c;
    if (channel == "IRRR_CORRECTION" && c.decode(b->data, 0, static_cast<int>(b->data_size)) > 0) {
      step_corrections += c.step >= 0 ? 1 : 0;
    }
    service->Receive(channel, static_cast<const uint8_t*>(b->data), static_cast<int>(b->data_size));
  }
};

// Runs the worker until its queue is empty (it takes at most 256 inputs at a time).
inline void ApplyQueued(Service* service) {
  while (service->ProcessQueued(std::chrono::milliseconds(0)) > 0) {
  }
}

inline IrrrOptions TestOptions() {
  IrrrOptions options;
  options.cluster_gap = 10.0;
  return options;
}

inline keyframe_t Keyframe(int32_t session, int64_t key) {
  keyframe_t k{};
  k.header = {0, key, "robot"};
  k.robot_id = 0;
  k.session_id = session;
  k.key = key;
  k.stamp_utime = key * 1000000;
  k.dim = keyframe_t::DIM_SE2;
  k.odom_pose = PoseToWire(Pose2(key, 0.0, 0.0));
  k.has_odom_edge = key > 0;
  k.odom_delta = PoseToWire(Pose2(1.0, 0.0, 0.0));
  InformationToWire<Pose2>(Pose2::Matrix::Identity() * 100.0, k.information);
  return k;
}

inline loop_hypothesis_t Loop(int64_t id, int64_t from, int64_t to) {
  loop_hypothesis_t l{};
  l.header = {0, id, "robot"};
  l.hypothesis_id = id;
  l.key_from = from;
  l.key_to = to;
  l.dim = keyframe_t::DIM_SE2;
  l.measurement = PoseToWire(Pose2(static_cast<double>(to - from), 0.0, 0.0));
  InformationToWire<Pose2>(Pose2::Matrix::Identity() * 100.0, l.information);
  l.score = 1.0f;
  return l;
}

// Sends messages into a service as producers would: header.seq counts from 0 per sender, over
// all its channels.
class Producer {
 public:
  Producer(Service* service, DaemonChannels channels)
      : service_(service), channels_(std::move(channels)) {}

  template <class Message>
  std::vector<uint8_t> Stamp(Message m) {
    m.header.seq = next_[m.header.sender]++;
    return EncodeMessage(m);
  }
  // Sends and, with `apply`, lets the worker apply it (and whatever was queued before it) at once.
  template <class Message>
  void Send(const Message& m, bool apply = true) {
    Raw(ChannelOf(m), Stamp(m), apply);
  }
  // Bytes as they are (not stamped).
  void Raw(const std::string& channel, const std::vector<uint8_t>& bytes, bool apply = true) {
    service_->Receive(channel, bytes.data(), static_cast<int>(bytes.size()));
    if (apply) ApplyQueued(service_);
  }
  std::string ChannelOf(const keyframe_t&) const { return channels_.keyframe; }
  std::string ChannelOf(const loop_hypothesis_t&) const { return channels_.loop; }
  std::string ChannelOf(const session_event_t&) const { return channels_.session; }

 private:
  Service* service_;
  DaemonChannels channels_;
  std::map<std::string, int64_t> next_;
};

inline session_event_t SessionEvent(int8_t event, int32_t session = 0) {
  session_event_t e{};
  e.header = {0, 0, "robot"};
  e.event = event;
  e.session_id = session;
  e.last_key = -1;
  e.last_hypothesis_id = -1;
  return e;
}

struct BadInput {
  const char* what;
  std::string channel;
  std::function<void(Producer&)> send;
  const char* field;  // expected error_t.field
};

// A two-session Intel prefix with grouped wrong inter-session loops (MakeTwoSessionIntel), its
// messages as irrr-inject sends them, and the undisturbed answer.
struct Case {
  PoseGraph<Pose2> graph;
  std::vector<int> graph_edge_of_file_edge;
  std::vector<ReplayMessage> messages;
  std::vector<LoopDecision> decisions;
  std::vector<Pose2> estimate;
};

inline IrrrOptions CaseOptions() {
  IrrrOptions options;
  options.cluster_gap = 10.0;
  return options;
}

inline const Case& IntelCase() {
  static const Case the_case = [] {
    Case c;
    // Each test runs in a process of its own and CTest runs them in parallel: the folder is the
    // process's, so that two tests building the case do not write the same files.
    const std::string dir = TestDirectory("reliability_case_" + std::to_string(::getpid()));
    const std::string path = MakeTwoSessionIntel(dir);
    GraphFile<Pose2> file;
    REQUIRE(LoadPoseGraph(
                path, FileFormat::kG2o, ReadOptions(), &file, &c.graph, &c.graph_edge_of_file_edge)
                .ok());
    c.messages = ReplayMessages(c.graph, c.graph_edge_of_file_edge, 0);
    c.messages.push_back(FlushMessage());
    c.decisions = RunIncrementalIrrr(c.graph, CaseOptions(), &c.estimate, nullptr);
    std::filesystem::remove_all(dir);
    return c;
  }();
  return the_case;
}

// The service's decisions and estimate equal the undisturbed answer: same decisions, poses
// within `tolerance`.
inline void CheckAnswer(const Service& service, const Case& c, double tolerance) {
  const std::vector<HypothesisDecision> decisions = service.Decisions();
  int loops = 0;
  for (const Edge<Pose2>& e : c.graph.edges()) loops += e.kind == EdgeKind::kLoop ? 1 : 0;
  REQUIRE(static_cast<int>(decisions.size()) == loops);
  int accepted = 0;
  for (const HypothesisDecision& d : decisions) {
    const LoopDecision& want = c.decisions[c.graph_edge_of_file_edge[d.hypothesis_id]];
    INFO("hypothesis " << d.hypothesis_id);
    CHECK(d.decision.state == want.state);
    CHECK(d.decision.cluster == want.cluster);
    CHECK(d.decision.step == want.step);
    accepted += d.decision.state == LoopState::kAccepted ? 1 : 0;
  }
  CHECK(accepted > 0);
  CHECK(accepted < loops);  // the wrong ones are rejected
  double worst = 0.0;
  int poses = 0;
  for (const Service::SessionEstimate& e : service.Estimates()) {
    for (size_t k = 0; k < e.poses.size(); ++k) {
      Pose2 got;
      REQUIRE(PoseFromWire(e.poses[k], "pose", &got).ok());
      const Pose2& want = c.estimate[c.graph.FindVertex(e.first_key + static_cast<int64_t>(k))];
      worst = std::max({worst,
                        (got.translation() - want.translation()).norm(),
                        std::abs(NormalizeAngle(got.yaw_rad() - want.yaw_rad()))});
      ++poses;
    }
  }
  CHECK(poses == c.graph.num_vertices());
  CHECK(worst <= tolerance);
}

// A producer over a lossy link: keeps its history, answers resync requests, resends its tail
// when the daemon's next_seq stalls (as irrr-inject does). Every datagram, resends included, is
// lost with probability `loss`, duplicated with `duplicate`, held back behind the next one with
// `reorder`.
class LossyProducer {
 public:
  LossyProducer(
      Service* service, RecordingSink* sink, const DaemonChannels& ch, double loss, uint32_t seed)
      : service_(service),
        sink_(sink),
        ch_(ch),
        sequencer_("robot", ch),
        loss_(loss),
        random_(seed) {}

  void Send(const ReplayMessage& m) { Transmit(sequencer_.Encode(m, NowUtime())); }

  // Until the service has taken everything sent: answers its requests, resends the tail.
  void Settle() {
    for (int round = 0; round < 100000 && NextSeq() <= sequencer_.last_seq(); ++round) {
      Pump();
      if (round % 20 == 19) {
        for (int64_t seq = NextSeq(); seq <= sequencer_.last_seq(); ++seq) {
          Transmit(sequencer_.Sent(seq));
        }
      }
    }
    Flush();
    ApplyQueued(service_);
  }

  // Lets time pass, the service tick and the producer answer its requests.
  void Pump() {
    std::this_thread::sleep_for(std::chrono::microseconds(300));
    service_->Tick();
    for (const resync_request_t& r : sink_->New<resync_request_t>(ch_.resync)) {
      ++requests;
      for (int32_t k = 0; k < r.n_ranges; ++k) {
        for (int64_t seq = r.first_seq[k]; seq <= std::min(r.last_seq[k], sequencer_.last_seq());
             ++seq) {
          Transmit(sequencer_.Sent(seq));
        }
      }
    }
    ApplyQueued(service_);
  }

  int64_t NextSeq() const {
    for (const sender_count_t& s : service_->CurrentStatus().senders) {
      if (s.sender == "robot") return s.next_seq;
    }
    return 0;
  }

  int64_t sent = 0;
  int64_t lost = 0;
  int64_t requests = 0;

 private:
  void Transmit(const MessageSequencer::Encoded& m) {
    ++sent;
    std::uniform_real_distribution<double> u(0.0, 1.0);
    if (u(random_) < loss_) {
      ++lost;
      return;
    }
    if (u(random_) < 0.05) Deliver(m);  // duplicated
    if (u(random_) < 0.05) {            // overtaken by the next datagram
      Flush();
      delayed_.push_back(m);
      return;
    }
    Deliver(m);
    Flush();
  }
  void Flush() {
    for (const auto& m : delayed_) Deliver(m);
    delayed_.clear();
  }
  void Deliver(const MessageSequencer::Encoded& m) {
    service_->Receive(m.first, m.second.data(), static_cast<int>(m.second.size()));
  }

  Service* service_;
  RecordingSink* sink_;
  DaemonChannels ch_;
  MessageSequencer sequencer_;
  double loss_;
  std::mt19937 random_;
  std::vector<MessageSequencer::Encoded> delayed_;
};

inline DaemonOptions FastResync() {
  DaemonOptions daemon;
  daemon.resync.interval_ms = 1;
  daemon.resync.give_up_ms = 60000;
  return daemon;
}

inline void FlipByte(const std::string& path, long offset) {
  std::FILE* f = std::fopen(path.c_str(), "r+b");
  REQUIRE(f != nullptr);
  REQUIRE(std::fseek(f, offset, SEEK_SET) == 0);
  const int byte = std::fgetc(f);
  REQUIRE(std::fseek(f, offset, SEEK_SET) == 0);
  std::fputc(byte ^ 0x5a, f);
  std::fclose(f);
}

// A first keyframe (key 0) of (robot, session) from `sender` with header.seq `seq`, applied.
inline void SendFirstKeyframe(Service* service,
                              const DaemonChannels& ch,
                              const std::string& sender,
                              int32_t robot,
                              int32_t session,
                              int64_t seq) {
  keyframe_t k{};
  k.header = {0, seq, sender};
  k.robot_id = robot;
  k.session_id = session;
  k.key = 0;
  k.dim = keyframe_t::DIM_SE2;
  k.odom_pose = PoseToWire(Pose2());
  const std::vector<uint8_t> bytes = EncodeMessage(k);
  service->Receive(ch.keyframe, bytes.data(), static_cast<int>(bytes.size()));
  ApplyQueued(service);
}

}  // namespace irrr

#endif  // IRRR_TESTS_SERVICE_HELPERS_H_
