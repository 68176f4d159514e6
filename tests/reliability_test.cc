// Nothing lost, nobody let in: each sender's order restored (sequencer.h), the journal (torn
// tails), and the service under loss, duplicates, reordering, a crash and restart, limits and an
// allow-list, each against the answer of an undisturbed run.

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <mutex>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <spdlog/spdlog.h>
#include <catch2/catch.hpp>

#include "clients/common/graph_files.h"
#include "clients/common/replay_messages.h"
#include "core/irrr.h"
#include "daemon/journal.h"
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
namespace {

using Catch::Matchers::Contains;
using Clock = std::chrono::steady_clock;

const bool kQuiet = [] {
  spdlog::set_level(spdlog::level::off);
  return true;
}();

// ---- Sequencer ----

TEST_CASE("Sequencer: each sender's messages come out in seq order, once each", "[reliability]") {
  SequencerLimits limits;
  limits.interval = std::chrono::milliseconds(10);
  limits.give_up = std::chrono::milliseconds(100);
  Sequencer<int> sequencer(limits);
  std::vector<int> out;
  auto take = [&out](int&& v) {
    out.push_back(v);
    return true;
  };
  using Outcome = Sequencer<int>::Outcome;
  const auto t0 = Clock::now();
  CHECK(sequencer.Offer("a", 0, 0, t0, take) == Outcome::kTaken);
  CHECK(sequencer.Offer("a", 2, 2, t0, take) == Outcome::kHeld);
  CHECK(sequencer.Offer("a", 5, 5, t0, take) == Outcome::kHeld);
  CHECK(sequencer.Offer("b", 0, 100, t0, take) == Outcome::kTaken);  // senders are independent
  CHECK(sequencer.Offer("a", 2, 2, t0, take) == Outcome::kDuplicate);
  CHECK(sequencer.Offer("a", 0, 0, t0, take) == Outcome::kDuplicate);
  CHECK(out == std::vector<int>{0, 100});

  // Missing: 1, 3 and 4, asked for at once, then not again before the interval.
  std::vector<Sequencer<int>::Request> due = sequencer.DueRequests(t0);
  REQUIRE(due.size() == 1);
  CHECK(due[0].sender == "a");
  CHECK(due[0].ranges == std::vector<std::pair<int64_t, int64_t>>{{1, 1}, {3, 4}});
  CHECK(sequencer.DueRequests(t0 + std::chrono::milliseconds(5)).empty());
  CHECK(sequencer.DueRequests(t0 + std::chrono::milliseconds(11)).size() == 1);

  CHECK(sequencer.Offer("a", 1, 1, t0, take) == Outcome::kTaken);  // releases 2
  CHECK(sequencer.Offer("a", 4, 4, t0, take) == Outcome::kHeld);
  CHECK(out == std::vector<int>{0, 100, 1, 2});
  std::map<std::string, StreamCounts> counts = sequencer.Counts();
  CHECK(counts["a"].next_seq == 3);
  CHECK(counts["a"].last_seq == 5);
  CHECK(counts["a"].held == 2);
  CHECK(counts["a"].gaps == 3);
  CHECK(counts["a"].duplicates == 2);
  CHECK(counts["a"].requested == 6);

  // Seq 3 never comes: given up after give_up, 4 and 5 follow.
  CHECK(sequencer.GiveUp(t0 + std::chrono::milliseconds(50), take).empty());
  const auto skipped = sequencer.GiveUp(t0 + std::chrono::milliseconds(101), take);
  REQUIRE(skipped.size() == 1);
  CHECK(skipped[0].ranges == std::vector<std::pair<int64_t, int64_t>>{{3, 3}});
  CHECK(out == std::vector<int>{0, 100, 1, 2, 4, 5});
  counts = sequencer.Counts();
  CHECK(counts["a"].given_up == 1);
  CHECK(counts["a"].held == 0);
  CHECK(sequencer.Offer("a", 3, 3, t0, take) == Outcome::kDuplicate);  // too late

  // A receiver that refuses: the message is dropped and the stream waits for its resend.
  bool full = true;
  auto refusing = [&](int&& v) {
    if (full) return false;
    out.push_back(v);
    return true;
  };
  CHECK(sequencer.Offer("c", 0, 7, t0, refusing) == Outcome::kRefused);
  CHECK(sequencer.Counts()["c"].next_seq == 0);
  full = false;
  CHECK(sequencer.Offer("c", 0, 7, t0, refusing) == Outcome::kTaken);

  // Resume (after recovery from the journal): seqs below are duplicates.
  sequencer.Resume("d", 10);
  CHECK(sequencer.Offer("d", 9, 9, t0, take) == Outcome::kDuplicate);
  CHECK(sequencer.Offer("d", 10, 10, t0, take) == Outcome::kTaken);
}

TEST_CASE("Sequencer: held messages are bounded by max_held", "[reliability]") {
  SequencerLimits limits;
  limits.max_held = 3;
  Sequencer<int> sequencer(limits);
  auto take = [](int&&) { return true; };
  using Outcome = Sequencer<int>::Outcome;
  for (int seq = 1; seq <= 3; ++seq) {
    CHECK(sequencer.Offer("a", seq, seq, Clock::now(), take) == Outcome::kHeld);
  }
  CHECK(sequencer.Offer("a", 4, 4, Clock::now(), take) == Outcome::kHoldFull);
  CHECK(sequencer.total_held() == 3);
  CHECK(sequencer.Offer("a", 0, 0, Clock::now(), take) == Outcome::kTaken);
  CHECK(sequencer.total_held() == 0);
  CHECK(sequencer.Counts()["a"].next_seq == 4);  // 4 was dropped: it will be asked for
}

TEST_CASE("The stamp merge hands inputs over by (stamp, sender), waiting for open senders",
          "[reliability]") {
  using Merger = StampMerger<std::string>;
  const auto t0 = Clock::now();
  std::vector<std::string> out;
  auto take = [&out](std::string&& m) { out.push_back(m); };

  SECTION("two senders in any arrival order come out by stamp, ties by sender name") {
    Merger merger(std::chrono::milliseconds(1000), {});
    merger.Add("b", 10, true, "b10", t0);
    merger.Release(t0, take);
    CHECK(out == std::vector<std::string>{"b10"});  // "a" is not known yet: nothing to wait for
    merger.Add("a", 5, true, "a5", t0);
    merger.Add("a", Merger::kNoStamp, true, "a-loop", t0);  // follows a's latest stamp
    merger.Add("b", 20, true, "b20", t0);
    merger.Add("a", 20, true, "a20", t0);
    merger.Release(t0, take);
    // b20 waits while "a" has shown 20 and "b" is open: a20 and b20 tie, "a" first; then
    // nothing shows > 20 yet, so the last of them waits for the other's next stamp.
    CHECK(out == std::vector<std::string>{"b10", "a5", "a-loop", "a20"});
    CHECK(merger.held() == 1);
    merger.Add("a", 30, false, "a30-end", t0);  // "a" closes: it holds nobody back
    merger.Release(t0, take);
    CHECK(out == std::vector<std::string>{"b10", "a5", "a-loop", "a20", "b20"});
    CHECK(merger.held() == 1);  // a30-end waits: "b" is open and may still send up to 30
    merger.Add("b", 40, true, "b40", t0);
    merger.Add("b", 50, true, "b50", t0);
    merger.Release(t0, take);
    CHECK(out ==
          std::vector<std::string>{"b10", "a5", "a-loop", "a20", "b20", "a30-end", "b40", "b50"});
    CHECK(merger.held() == 0);
  }
  SECTION("a silent open sender is waited for at most the window") {
    Merger merger(std::chrono::milliseconds(100), {});
    merger.Add("a", 1, true, "a1", t0);
    merger.Add("b", 5, true, "b5", t0);
    merger.Add("b", 6, true, "b6", t0);
    CHECK(merger.Release(t0, take) == 0);
    CHECK(out == std::vector<std::string>{"a1"});
    CHECK(merger.Release(t0 + std::chrono::milliseconds(50), take) == 0);
    CHECK(out.size() == 1);
    CHECK(merger.Release(t0 + std::chrono::milliseconds(150), take) == 2);
    CHECK(out == std::vector<std::string>{"a1", "b5", "b6"});
  }
  SECTION("expected senders are waited for before they are heard") {
    Merger merger(std::chrono::milliseconds(1000), {"robot1", "robot2"});
    merger.Add("robot2", 150, true, "r2-150", t0);
    merger.Release(t0, take);
    CHECK(out.empty());  // robot1 may still send earlier stamps
    merger.Add("robot1", 0, true, "r1-0", t0);
    merger.Add("robot1", 149, true, "r1-149", t0);
    merger.Release(t0, take);
    CHECK(out == std::vector<std::string>{"r1-0", "r1-149"});
    merger.Add("robot1", 149, false, "r1-end", t0);
    merger.Release(t0, take);
    CHECK(out == std::vector<std::string>{"r1-0", "r1-149", "r1-end", "r2-150"});
  }
}

// ---- Journal ----

JournalRecord Record(uint8_t fill, size_t size) {
  JournalRecord r;
  r.kind = static_cast<JournalRecord::Kind>(fill % 3);
  r.received_utime = 1000 + fill;
  r.bytes.assign(size, fill);
  return r;
}

int64_t FileSize(const std::string& path) {
  std::FILE* f = std::fopen(path.c_str(), "rb");
  REQUIRE(f != nullptr);
  std::fseek(f, 0, SEEK_END);
  const int64_t size = std::ftell(f);
  std::fclose(f);
  return size;
}

TEST_CASE("Journal: records come back as written; a torn or corrupt tail is dropped",
          "[reliability]") {
  const std::string dir = TestDirectory("journal");
  const std::string path = dir + "/journal";
  std::remove(path.c_str());
  std::vector<JournalRecord> written;
  std::vector<int64_t> ends;  // file size after each record
  {
    Journal journal;
    JournalRecovery recovery;
    REQUIRE(journal.Open(path, JournalSyncPolicy::kNever, &recovery).ok());
    CHECK(recovery.records.empty());
    for (uint8_t k = 0; k < 20; ++k) {
      written.push_back(Record(k, 10 + 7 * k));
      REQUIRE(journal.Append({written.back()}).ok());
      ends.push_back(journal.size_bytes());
    }
  }
  CHECK(FileSize(path) == ends.back());
  auto reopen = [&](JournalRecovery* recovery) {
    Journal journal;
    const Status s = journal.Open(path, JournalSyncPolicy::kBatch, recovery);
    INFO(s.message());
    REQUIRE(s.ok());
  };
  JournalRecovery recovery;
  reopen(&recovery);
  REQUIRE(recovery.records.size() == written.size());
  for (size_t k = 0; k < written.size(); ++k) {
    CHECK(recovery.records[k].kind == written[k].kind);
    CHECK(recovery.records[k].received_utime == written[k].received_utime);
    CHECK(recovery.records[k].bytes == written[k].bytes);
  }
  CHECK(recovery.dropped_bytes == 0);

  // A crash in the middle of the last write: every cut inside the last record.
  const int64_t last_start = ends[ends.size() - 2];
  for (int64_t cut = last_start + 1; cut < ends.back(); cut += 5) {
    REQUIRE(truncate(path.c_str(), cut) == 0);
    reopen(&recovery);
    INFO("cut at " << cut);
    CHECK(recovery.records.size() == written.size() - 1);
    CHECK(recovery.dropped_bytes == cut - last_start);
    CHECK(FileSize(path) == last_start);  // truncated away
    // Appending goes on from there, readable.
    {
      Journal journal;
      JournalRecovery unused;
      REQUIRE(journal.Open(path, JournalSyncPolicy::kNever, &unused).ok());
      REQUIRE(journal.Append({written.back()}).ok());
    }
    reopen(&recovery);
    CHECK(recovery.records.size() == written.size());
    CHECK(recovery.dropped_bytes == 0);
  }

  // A flipped byte in record 12: it and everything after are dropped, with the reason.
  {
    const int fd = open(path.c_str(), O_RDWR);
    REQUIRE(fd >= 0);
    const off_t at = static_cast<off_t>(ends[11] + 20);
    uint8_t byte = 0;
    REQUIRE(pread(fd, &byte, 1, at) == 1);
    byte ^= 0x40;
    REQUIRE(pwrite(fd, &byte, 1, at) == 1);
    close(fd);
  }
  reopen(&recovery);
  CHECK(recovery.records.size() == 12);
  CHECK(recovery.dropped_bytes == ends.back() - ends[11]);
  CHECK_THAT(recovery.dropped_reason, Contains("CRC"));

  // Not a journal: refused, untouched.
  WriteText(dir + "/other", "hello world, not a journal");
  Journal journal;
  const Status s = journal.Open(dir + "/other", JournalSyncPolicy::kNever, &recovery);
  CHECK_FALSE(s.ok());
  CHECK_THAT(s.message(), Contains("not an irrrd journal"));
  CHECK(ReadText(dir + "/other") == "hello world, not a journal");
}

// ---- The service under loss, restarts, limits ----

// A two-session Intel prefix with grouped wrong inter-session loops (MakeTwoSessionIntel), its
// messages as irrr-inject sends them, and the undisturbed answer.
struct Case {
  PoseGraph<Pose2> graph;
  std::vector<int> graph_edge_of_file_edge;
  std::vector<ReplayMessage> messages;
  std::vector<LoopDecision> decisions;
  std::vector<Pose2> estimate;
};

IrrrOptions CaseOptions() {
  IrrrOptions options;
  options.cluster_gap = 10.0;
  return options;
}

const Case& IntelCase() {
  static const Case the_case = [] {
    Case c;
    const std::string path = MakeTwoSessionIntel(TestDirectory("reliability_case"));
    GraphFile<Pose2> file;
    REQUIRE(LoadPoseGraph(
                path, FileFormat::kG2o, ReadOptions(), &file, &c.graph, &c.graph_edge_of_file_edge)
                .ok());
    c.messages = ReplayMessages(c.graph, c.graph_edge_of_file_edge, 0);
    c.messages.push_back(FlushMessage());
    c.decisions = RunIncrementalIrrr(c.graph, CaseOptions(), &c.estimate, nullptr);
    return c;
  }();
  return the_case;
}

// The service's decisions and estimate equal the undisturbed answer: same decisions, poses
// within `tolerance`.
void CheckAnswer(const Service& service, const Case& c, double tolerance) {
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
    service_->ProcessQueued(std::chrono::milliseconds(0));
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
    service_->ProcessQueued(std::chrono::milliseconds(0));
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

DaemonOptions FastResync() {
  DaemonOptions daemon;
  daemon.resync.interval_ms = 1;
  daemon.resync.give_up_ms = 60000;
  return daemon;
}

TEST_CASE("Under 10% loss, duplicates and reordering the service decides as without them",
          "[reliability]") {
  const Case& c = IntelCase();
  for (uint32_t seed : {1u, 2u}) {
    RecordingSink sink;
    const DaemonOptions daemon = FastResync();
    Service service(daemon, CaseOptions(), &sink);
    LossyProducer producer(&service, &sink, daemon.channels, 0.10, seed);
    for (const ReplayMessage& m : c.messages) {
      producer.Send(m);
      producer.Pump();
    }
    producer.Settle();
    INFO("seed " << seed << ": " << producer.sent << " datagrams, " << producer.lost << " lost, "
                 << producer.requests << " resync requests");
    CHECK(producer.lost > 0.05 * producer.sent);
    CHECK(producer.requests > 0);
    const status_t status = service.CurrentStatus();
    CHECK(status.n_errors == 0);
    REQUIRE(status.n_senders == 1);
    CHECK(status.senders[0].next_seq == static_cast<int64_t>(c.messages.size()));
    CHECK(status.senders[0].gaps > 0);
    CHECK(status.senders[0].duplicates > 0);
    CHECK(status.senders[0].given_up == 0);
    CheckAnswer(service, c, 1e-9);
  }
}

// The state it had: the same decisions and, bit for bit, the same estimate.
void CheckSameState(const std::vector<HypothesisDecision>& now,
                    const std::vector<Service::SessionEstimate>& estimate,
                    const std::vector<HypothesisDecision>& before,
                    const std::vector<Service::SessionEstimate>& estimate_before) {
  REQUIRE(now.size() == before.size());
  for (size_t k = 0; k < now.size(); ++k) {
    CHECK(now[k].hypothesis_id == before[k].hypothesis_id);
    CHECK(now[k].decision.state == before[k].decision.state);
    CHECK(now[k].decision.step == before[k].decision.step);
    CHECK(now[k].decision.cluster == before[k].decision.cluster);
    CHECK((now[k].decision.chi2 == before[k].decision.chi2 ||
           (std::isnan(now[k].decision.chi2) && std::isnan(before[k].decision.chi2))));
  }
  REQUIRE(estimate.size() == estimate_before.size());
  for (size_t s = 0; s < estimate.size(); ++s) {
    REQUIRE(estimate[s].poses.size() == estimate_before[s].poses.size());
    for (size_t k = 0; k < estimate[s].poses.size(); ++k) {
      for (int i = 0; i < 3; ++i)
        CHECK(estimate[s].poses[k].t[i] == estimate_before[s].poses[k].t[i]);
      for (int i = 0; i < 4; ++i)
        CHECK(estimate[s].poses[k].q[i] == estimate_before[s].poses[k].q[i]);
    }
  }
}

void CheckSameState(const Service& service,
                    const std::vector<HypothesisDecision>& before,
                    const std::vector<Service::SessionEstimate>& estimate_before) {
  CheckSameState(service.Decisions(), service.Estimates(), before, estimate_before);
}

TEST_CASE("A service that dies mid-stream restarts from its journal and ends as if it had not",
          "[reliability]") {
  const Case& c = IntelCase();
  // Without snapshots a restart re-runs every step; with them only the steps after the last one.
  const int snapshot_every = GENERATE(0, 40);
  INFO("daemon.journal.snapshot_every " << snapshot_every);
  const std::string dir = TestDirectory("reliability_restart");
  const std::string path = dir + "/journal";
  std::remove(path.c_str());
  std::remove((path + ".snapshot").c_str());
  DaemonOptions daemon = FastResync();
  daemon.journal.snapshot_every = snapshot_every;
  MessageSequencer producer("robot", daemon.channels);
  std::vector<MessageSequencer::Encoded> encoded;
  for (const ReplayMessage& m : c.messages) encoded.push_back(producer.Encode(m, NowUtime()));

  // Dies at several points: some inputs applied (journaled), some only queued (lost with it).
  std::mt19937 random(11);
  std::vector<size_t> deaths;
  for (int k = 0; k < 6; ++k) deaths.push_back(1 + random() % (encoded.size() - 1));
  std::sort(deaths.begin(), deaths.end());
  size_t next = 0;
  int restored_from_snapshot = 0;
  std::vector<HypothesisDecision> before;
  std::vector<Service::SessionEstimate> estimate_before;
  for (size_t death = 0; death <= deaths.size(); ++death) {
    RecordingSink sink;
    Service service(daemon, CaseOptions(), &sink);
    Journal journal;
    JournalRecovery recovery;
    REQUIRE(journal.Open(path, JournalSyncPolicy::kNever, &recovery).ok());
    if (death > 0) {
      service.Recover(recovery, path);
      const status_t status = service.CurrentStatus();
      CHECK(status.n_recovered == static_cast<int64_t>(recovery.records.size()));
      CHECK_THAT(status.recovery, Contains("replayed"));
      if (snapshot_every > 0 && recovery.records.size() >= static_cast<size_t>(snapshot_every)) {
        CHECK_THAT(status.recovery, Contains("restored the snapshot"));
        ++restored_from_snapshot;
      }
      CheckSameState(service, before, estimate_before);
      // It announces a complete solution.
      const std::vector<correction_t> corrections =
          sink.New<correction_t>(daemon.channels.correction);
      REQUIRE(corrections.size() == 1);
      CHECK(corrections[0].complete == 1);
    }
    service.SetJournal(&journal);
    // The producer goes on where it was; what the dead service had queued but not journaled
    // is asked for again.
    const size_t stop = death < deaths.size() ? deaths[death] : encoded.size();
    for (; next < stop; ++next) {
      service.Receive(encoded[next].first,
                      encoded[next].second.data(),
                      static_cast<int>(encoded[next].second.size()));
      // Applies all but the last few inputs before dying.
      if (next + 3 < stop) service.ProcessQueued(std::chrono::milliseconds(0));
      std::this_thread::sleep_for(std::chrono::microseconds(200));
      service.Tick();
      for (const resync_request_t& r : sink.New<resync_request_t>(daemon.channels.resync)) {
        for (int32_t k = 0; k < r.n_ranges; ++k) {
          for (int64_t seq = r.first_seq[k]; seq <= std::min<int64_t>(r.last_seq[k], next - 1);
               ++seq) {
            service.Receive(encoded[seq].first,
                            encoded[seq].second.data(),
                            static_cast<int>(encoded[seq].second.size()));
          }
        }
      }
    }
    if (death == deaths.size()) {
      service.ProcessQueued(std::chrono::milliseconds(0));
      const status_t status = service.CurrentStatus();
      REQUIRE(status.n_senders == 1);
      CHECK(status.senders[0].next_seq == static_cast<int64_t>(encoded.size()));
      CheckAnswer(service, c, 1e-9);
    } else {
      // Killed: whatever is queued is lost; the state is what was applied (and journaled).
      before = service.Decisions();
      estimate_before = service.Estimates();
    }
  }
  if (snapshot_every > 0) CHECK(restored_from_snapshot >= 3);
}

// Runs the Intel case through a service with a journal at `path`, writing a snapshot after
// `snapshot_after` inputs (and then no more); returns its decisions and estimate at the end.
void RunWithSnapshot(const std::string& path,
                     size_t snapshot_after,
                     std::vector<HypothesisDecision>* decisions,
                     std::vector<Service::SessionEstimate>* estimate) {
  const Case& c = IntelCase();
  std::remove(path.c_str());
  std::remove((path + ".snapshot").c_str());
  DaemonOptions daemon = FastResync();
  daemon.journal.snapshot_every = 1 << 30;  // only when asked
  RecordingSink sink;
  Service service(daemon, CaseOptions(), &sink);
  Journal journal;
  JournalRecovery recovery;
  REQUIRE(journal.Open(path, JournalSyncPolicy::kNever, &recovery).ok());
  service.SetJournal(&journal);
  MessageSequencer producer("robot", daemon.channels);
  for (size_t k = 0; k < c.messages.size(); ++k) {
    const auto encoded = producer.Encode(c.messages[k], NowUtime());
    service.Receive(encoded.first, encoded.second.data(), static_cast<int>(encoded.second.size()));
    service.ProcessQueued(std::chrono::milliseconds(0));
    if (k + 1 == snapshot_after) REQUIRE(service.WriteSnapshot().ok());
  }
  *decisions = service.Decisions();
  *estimate = service.Estimates();
}

// Restarts from `path` (and its snapshot, if any); returns the recovery text.
std::string Restart(const std::string& path,
                    const IrrrOptions& options,
                    std::vector<HypothesisDecision>* decisions,
                    std::vector<Service::SessionEstimate>* estimate) {
  RecordingSink sink;
  Service service(FastResync(), options, &sink);
  Journal journal;
  JournalRecovery recovery;
  REQUIRE(journal.Open(path, JournalSyncPolicy::kNever, &recovery).ok());
  service.Recover(recovery, path);
  *decisions = service.Decisions();
  *estimate = service.Estimates();
  return service.CurrentStatus().recovery;
}

void FlipByte(const std::string& path, long offset) {
  std::FILE* f = std::fopen(path.c_str(), "r+b");
  REQUIRE(f != nullptr);
  REQUIRE(std::fseek(f, offset, SEEK_SET) == 0);
  const int byte = std::fgetc(f);
  REQUIRE(std::fseek(f, offset, SEEK_SET) == 0);
  std::fputc(byte ^ 0x5a, f);
  std::fclose(f);
}

TEST_CASE("A snapshot body reads back as written, and any cut of it is refused", "[reliability]") {
  IrrrStepState<Pose3> state;
  state.decisions.resize(3);
  state.decisions[1] = {0, LoopState::kReversed, 4, 12.5, 12.59};
  state.estimate = {Pose3(), Pose3::Exp((Pose3::Tangent() << 1, 2, 3, 0.1, -0.2, 0.3).finished())};
  state.clusters.resize(2);
  state.clusters[0].links = {1, 2};
  state.clusters[0].session_a = 1;
  state.clusters[0].in_good = true;
  state.clusters[1].opponents = {0};
  state.clusters[1].in_reject = true;
  state.cluster_of = {0, 1};
  state.steps = 7;
  state.judged = 2;
  SnapshotWriter w;
  w.String("options");
  w.StepState(state);
  const std::vector<uint8_t> body = w.bytes();

  SnapshotReader r(body);
  std::string text;
  IrrrStepState<Pose3> back;
  REQUIRE(r.String(&text));
  REQUIRE(r.StepState(&back));
  CHECK(r.at_end());
  CHECK(text == "options");
  REQUIRE(back.decisions.size() == 3);
  CHECK(back.decisions[1].state == LoopState::kReversed);
  CHECK(back.decisions[1].threshold == 12.59);
  CHECK(std::isnan(back.decisions[0].chi2));
  REQUIRE(back.estimate.size() == 2);
  CHECK(back.estimate[1].translation() == state.estimate[1].translation());
  CHECK(back.estimate[1].quaternion().coeffs() == state.estimate[1].quaternion().coeffs());
  CHECK(back.clusters[0].links == std::vector<int>{1, 2});
  CHECK((back.clusters[0].in_good && !back.clusters[0].in_r && back.clusters[1].in_reject));
  CHECK(back.clusters[1].opponents == std::vector<int>{0});
  CHECK((back.steps == 7 && back.judged == 2 && back.cluster_of == state.cluster_of));

  for (size_t cut = 0; cut < body.size(); ++cut) {
    const std::vector<uint8_t> part(body.begin(), body.begin() + static_cast<long>(cut));
    SnapshotReader partial(part);
    IrrrStepState<Pose3> ignored;
    const bool ok = partial.String(&text) && partial.StepState(&ignored) && partial.at_end();
    CHECK(!ok);
  }
}

TEST_CASE("A restart from a snapshot runs no step it covers and rebuilds the same state",
          "[reliability]") {
  const Case& c = IntelCase();
  const std::string path = TestDirectory("reliability_snapshot") + "/journal";
  std::vector<HypothesisDecision> decisions;
  std::vector<Service::SessionEstimate> estimate;
  std::vector<HypothesisDecision> recovered;
  std::vector<Service::SessionEstimate> recovered_estimate;

  SECTION("a snapshot of everything: nothing is replayed with its steps") {
    RunWithSnapshot(path, c.messages.size(), &decisions, &estimate);
    const std::string text = Restart(path, CaseOptions(), &recovered, &recovered_estimate);
    CHECK_THAT(text,
               Contains("restored the snapshot of the first " + std::to_string(c.messages.size()) +
                        " inputs, then replayed 0 inputs"));
    CheckSameState(recovered, recovered_estimate, decisions, estimate);
  }
  SECTION("a snapshot halfway: the second half is replayed with its steps") {
    RunWithSnapshot(path, c.messages.size() / 2, &decisions, &estimate);
    const std::string text = Restart(path, CaseOptions(), &recovered, &recovered_estimate);
    CHECK_THAT(text,
               Contains("then replayed " +
                        std::to_string(c.messages.size() - c.messages.size() / 2) + " inputs"));
    CheckSameState(recovered, recovered_estimate, decisions, estimate);
  }
  SECTION("a corrupt snapshot is not used: the whole journal is replayed") {
    RunWithSnapshot(path, c.messages.size() / 2, &decisions, &estimate);
    FlipByte(path + ".snapshot", 100);
    const std::string text = Restart(path, CaseOptions(), &recovered, &recovered_estimate);
    CHECK_THAT(text,
               !Contains("restored the snapshot") &&
                   Contains("replayed " + std::to_string(c.messages.size()) + " inputs"));
    CheckSameState(recovered, recovered_estimate, decisions, estimate);
  }
  SECTION("a snapshot of another journal is not used") {
    RunWithSnapshot(path, c.messages.size() / 2, &decisions, &estimate);
    FlipByte(path, 40);  // inside the first record: the journal now ends before it
    const std::string text = Restart(path, CaseOptions(), &recovered, &recovered_estimate);
    CHECK_THAT(text, !Contains("restored the snapshot") && Contains("replayed 0 inputs"));
    CHECK(recovered.empty());
  }
  SECTION("under other irrr options the journal is decided again") {
    RunWithSnapshot(path, c.messages.size(), &decisions, &estimate);
    IrrrOptions other = CaseOptions();
    other.alpha = 0.99;
    const std::string text = Restart(path, other, &recovered, &recovered_estimate);
    CHECK_THAT(text, !Contains("restored the snapshot"));
    // Decided under alpha 0.99: what RunIncrementalIrrr says with those options.
    const std::vector<LoopDecision> expected =
        RunIncrementalIrrr<Pose2>(c.graph, other, nullptr, nullptr);
    REQUIRE(recovered.size() == decisions.size());
    int differ_from_095 = 0;
    for (size_t k = 0; k < recovered.size(); ++k) {
      const int edge = c.graph_edge_of_file_edge[recovered[k].hypothesis_id];
      CHECK(recovered[k].decision.state == expected[edge].state);
      CHECK(recovered[k].decision.step == expected[edge].step);
      differ_from_095 += recovered[k].decision.threshold != decisions[k].decision.threshold;
    }
    CHECK(differ_from_095 > 0);
  }
}

// A first keyframe (key 0) of (robot, session) from `sender` with header.seq `seq`, applied.
void SendFirstKeyframe(Service* service,
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
  service->ProcessQueued(std::chrono::milliseconds(0));
}

TEST_CASE("The allow-list ignores other senders and robots, and counts them", "[reliability]") {
  RecordingSink sink;
  DaemonOptions daemon;
  daemon.allowed_senders = {"robot3/*", "base"};
  daemon.allowed_robots = {3};
  Service service(daemon, CaseOptions(), &sink);
  auto send = [&](const std::string& sender, int32_t robot, int64_t seq) {
    SendFirstKeyframe(&service, daemon.channels, sender, robot, 0, seq);
  };
  send("robot3/frontend", 3, 0);
  send("intruder", 3, 0);
  send("robot4/frontend", 4, 0);
  send("base", 4, 0);    // an allowed sender naming a robot that is not allowed
  send("robot3", 3, 0);  // "robot3/*" needs the slash
  const status_t status = service.CurrentStatus();
  CHECK(status.n_keyframes == 1);
  CHECK(status.n_ignored == 4);
  CHECK(status.n_errors == 0);
  CHECK(sink.New<error_t>(daemon.channels.error).empty());
}

TEST_CASE("At a limit the status says DEGRADED and why, and nothing grows past it",
          "[reliability]") {
  RecordingSink sink;
  DaemonOptions daemon;
  daemon.limits.max_sessions = 2;
  daemon.limits.max_held = 5;
  Service service(daemon, CaseOptions(), &sink);
  auto keyframe = [&](const std::string& sender, int32_t session, int64_t seq) {
    SendFirstKeyframe(&service, daemon.channels, sender, 0, session, seq);
  };
  keyframe("a", 0, 0);
  service.PublishStatus(status_t::RUNNING);
  CHECK(sink.New<status_t>(daemon.channels.status).back().state == status_t::RUNNING);
  keyframe("a", 1, 1);
  keyframe("a", 2, 2);  // a third session: refused
  status_t status = service.CurrentStatus();
  CHECK(status.n_sessions == 2);
  CHECK_THAT(status.degraded_reason, Contains("max_sessions"));
  const std::vector<error_t> errors = sink.New<error_t>(daemon.channels.error);
  REQUIRE(errors.size() == 1);
  CHECK_THAT(errors[0].reason, Contains("max_sessions"));
  service.PublishStatus(status_t::RUNNING);
  const status_t published = sink.New<status_t>(daemon.channels.status).back();
  CHECK(published.state == status_t::DEGRADED);
  CHECK_THAT(published.degraded_reason, Contains("max_sessions"));

  // Held inputs (a lost seq 3 of "b"): at most max_held; the rest are refused, asked for later.
  for (int64_t seq = 1; seq <= 8; ++seq) keyframe("b", 0, seq);
  status = service.CurrentStatus();
  for (const sender_count_t& s : status.senders) {
    if (s.sender == "b") CHECK(s.held == 5);
  }
  CHECK_THAT(status.degraded_reason, Contains("max_held"));
}

TEST_CASE("Another daemon publishing on our correction channel is noticed, ours are not",
          "[reliability]") {
  RecordingSink sink;
  DaemonOptions daemon;
  daemon.daemon_id = "base-a";
  Service service(daemon, CaseOptions(), &sink);
  auto hear = [&](const std::string& sender) {
    correction_t c{};
    c.header.sender = sender;
    c.solution_id = 1;
    const std::vector<uint8_t> bytes = EncodeMessage(c);
    service.Receive(daemon.channels.correction, bytes.data(), static_cast<int>(bytes.size()));
  };
  hear("base-a");  // our own, back over multicast
  CHECK(service.CurrentStatus().degraded_reason.empty());
  hear("base-b");
  hear("base-b");
  const status_t status = service.CurrentStatus();
  CHECK(status.degraded_reason == "daemon \"base-b\" also publishes on IRRR_CORRECTION");
  CHECK(status.n_errors == 0);
  service.PublishStatus(status_t::RUNNING);
  const std::vector<status_t> published = sink.Decoded<status_t>(daemon.channels.status);
  REQUIRE(published.size() == 1);
  CHECK(published[0].state == status_t::DEGRADED);
}

TEST_CASE("A consumer's solution request is answered with every pose and every verdict",
          "[reliability]") {
  const Case& c = IntelCase();
  RecordingSink sink;
  const DaemonOptions daemon = FastResync();
  Service service(daemon, CaseOptions(), &sink);
  MessageSequencer producer("robot", daemon.channels);
  for (const ReplayMessage& m : c.messages) {
    const auto [channel, bytes] = producer.Encode(m, NowUtime());
    service.Receive(channel, bytes.data(), static_cast<int>(bytes.size()));
  }
  service.ProcessQueued(std::chrono::milliseconds(0));
  sink.New<correction_t>(daemon.channels.correction);
  sink.New<verdicts_t>(daemon.channels.verdicts);
  sink.New<solution_t>(daemon.channels.solution);

  solution_request_t request{};
  request.header = {0, 0, "late-listener"};
  request.reason = "test";
  const std::vector<uint8_t> bytes = EncodeMessage(request);
  service.Receive(daemon.channels.solution_request, bytes.data(), static_cast<int>(bytes.size()));
  service.ProcessQueued(std::chrono::milliseconds(0));
  const std::vector<correction_t> corrections = sink.New<correction_t>(daemon.channels.correction);
  REQUIRE(corrections.size() == 1);
  const correction_t& complete = corrections[0];
  CHECK(complete.complete == 1);
  CHECK(complete.n_sessions == c.graph.num_sessions());
  int verdicts = 0;
  for (const verdicts_t& chunk : sink.New<verdicts_t>(daemon.channels.verdicts)) {
    CHECK(chunk.solution_id == complete.solution_id);
    verdicts += chunk.n_verdicts;
  }
  CHECK(verdicts == static_cast<int>(service.Decisions().size()));
  int poses = 0;
  for (const solution_t& chunk : sink.New<solution_t>(daemon.channels.solution)) {
    CHECK(chunk.solution_id == complete.solution_id);
    poses += chunk.n_poses;
  }
  CHECK(poses == c.graph.num_vertices());
}

}  // namespace
}  // namespace irrr
