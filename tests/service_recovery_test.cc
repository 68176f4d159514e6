// The service's recovery (daemon/service_recovery.cc): a service that dies restarts from its
// journal, or from a snapshot and the journal after it, into the state it had.

#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
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
#include "tests/service_helpers.h"
#include "tests/test_files.h"

namespace irrr {
namespace {

using Catch::Matchers::Contains;
using Clock = std::chrono::steady_clock;

// A restart from a snapshot rebuilds the warm engine's good-set estimate at the optimum of the
// snapshot's poses, where the original kept its linearization points while their quadratic model
// held (IncrementalSolverOptions::model_tolerance): the decisions that follow are the same, their
// chi2 agree to this fraction of the larger of chi2 and the threshold, and the poses to this many
// metres and quaternion components. Measured: up to 2.5e-3 (poses, along the estimate's weakest
// directions, where a tenth of a degree of freedom's chi2 moves them furthest).
constexpr double kRestoredTolerance = 1e-2;

// The state it had: the same decisions and the same estimate, bit for bit when every step ran
// again (`tolerance` 0), to `tolerance` after a snapshot.
void CheckSameState(const std::vector<HypothesisDecision>& now,
                    const std::vector<Service::SessionEstimate>& estimate,
                    const std::vector<HypothesisDecision>& before,
                    const std::vector<Service::SessionEstimate>& estimate_before,
                    double tolerance) {
  auto close = [tolerance](double a, double b, double scale) {
    return a == b || std::abs(a - b) <= tolerance * scale;
  };
  REQUIRE(now.size() == before.size());
  for (size_t k = 0; k < now.size(); ++k) {
    CHECK(now[k].hypothesis_id == before[k].hypothesis_id);
    CHECK(now[k].decision.state == before[k].decision.state);
    CHECK(now[k].decision.step == before[k].decision.step);
    CHECK(now[k].decision.cluster == before[k].decision.cluster);
    CHECK((close(now[k].decision.chi2,
                 before[k].decision.chi2,
                 std::max(std::abs(before[k].decision.chi2), before[k].decision.threshold)) ||
           (std::isnan(now[k].decision.chi2) && std::isnan(before[k].decision.chi2))));
  }
  REQUIRE(estimate.size() == estimate_before.size());
  for (size_t s = 0; s < estimate.size(); ++s) {
    REQUIRE(estimate[s].poses.size() == estimate_before[s].poses.size());
    for (size_t k = 0; k < estimate[s].poses.size(); ++k) {
      for (int i = 0; i < 3; ++i)
        CHECK(close(estimate[s].poses[k].t[i], estimate_before[s].poses[k].t[i], 1.0));
      for (int i = 0; i < 4; ++i)
        CHECK(close(estimate[s].poses[k].q[i], estimate_before[s].poses[k].q[i], 1.0));
    }
  }
}

void CheckSameState(const Service& service,
                    const std::vector<HypothesisDecision>& before,
                    const std::vector<Service::SessionEstimate>& estimate_before,
                    double tolerance) {
  CheckSameState(service.Decisions(), service.Estimates(), before, estimate_before, tolerance);
}

TEST_CASE("A service that dies mid-stream restarts from its journal and ends as if it had not",
          "[reliability][slow]") {
  const Case& c = IntelCase();
  // Without snapshots a restart re-runs every step; with them only the steps after the last one.
  // Compacted (every 50 kB of the case's 0.8 MB of journal), a restart starts from the base.
  const auto [snapshot_every, compact_mb] = GENERATE(std::make_pair(0, 0.0),
                                                     std::make_pair(40, 0.0),
                                                     std::make_pair(40, 0.05),
                                                     std::make_pair(0, 0.05));
  INFO("daemon.journal.snapshot_every " << snapshot_every << ", compact_mb " << compact_mb);
  const std::string dir = TestDirectory("reliability_restart");
  const std::string path = dir + "/journal";
  for (const char* suffix : {"", ".snapshot", ".base"}) std::remove((path + suffix).c_str());
  DaemonOptions daemon = FastResync();
  daemon.journal.snapshot_every = snapshot_every;
  daemon.journal.compact_mb = compact_mb;
  const double tolerance = snapshot_every > 0 || compact_mb > 0 ? kRestoredTolerance : 0.0;
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
  int restored_from_base = 0;
  std::vector<HypothesisDecision> before;
  std::vector<Service::SessionEstimate> estimate_before;
  for (size_t death = 0; death <= deaths.size(); ++death) {
    RecordingSink sink;
    Service service(daemon, CaseOptions(), &sink);
    Journal journal;
    JournalRecovery recovery;
    REQUIRE(journal.Open(path, JournalSyncPolicy::kNever, &recovery).ok());
    if (death > 0) {
      REQUIRE(service.Recover(recovery, path).ok());
      const status_t status = service.CurrentStatus();
      CHECK(status.n_recovered == static_cast<int64_t>(recovery.records.size()));
      CHECK_THAT(status.recovery, Contains("replayed"));
      if (snapshot_every > 0 && recovery.records.size() >= static_cast<size_t>(snapshot_every)) {
        CHECK_THAT(status.recovery, Contains("restored the snapshot"));
        ++restored_from_snapshot;
      }
      if (recovery.first_record > 0) {
        CHECK_THAT(status.recovery,
                   Contains("restored the base of the first " +
                            std::to_string(recovery.first_record) + " inputs"));
        ++restored_from_base;
      }
      CheckSameState(service, before, estimate_before, tolerance);
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
      ApplyQueued(&service);
      const status_t status = service.CurrentStatus();
      REQUIRE(status.n_senders == 1);
      CHECK(status.senders[0].next_seq == static_cast<int64_t>(encoded.size()));
      CheckAnswer(service, c, 1e-9);
    } else {
      // Killed: whatever is queued is lost; the state is what was applied (and journaled).
      before = service.Decisions();
      estimate_before = service.Estimates();
    }
    // Compacted, the journal never holds much more than the bound (its last input or two).
    if (compact_mb > 0) CHECK(journal.size_bytes() < compact_mb * 1e6 + 2000);
  }
  if (snapshot_every > 0 && compact_mb == 0) CHECK(restored_from_snapshot >= 3);
  if (compact_mb > 0) CHECK(restored_from_base >= 3);
}

// Runs the Intel case through a service with a journal at `path` under `journal_options`, input
// by input or in batches (everything received before the worker runs); input by input, also
// writes a snapshot once `snapshot_after` inputs are applied (0: never asked). Returns its
// decisions and estimate at the end.
void RunJournaled(const std::string& path,
                  const DaemonJournal& journal_options,
                  bool batched,
                  size_t snapshot_after,
                  std::vector<HypothesisDecision>* decisions,
                  std::vector<Service::SessionEstimate>* estimate) {
  const Case& c = IntelCase();
  for (const char* suffix : {"", ".snapshot", ".base"}) std::remove((path + suffix).c_str());
  DaemonOptions daemon = FastResync();
  daemon.journal = journal_options;
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
    if (batched) continue;
    ApplyQueued(&service);
    if (k + 1 == snapshot_after) REQUIRE(service.WriteSnapshot().ok());
  }
  if (batched) ApplyQueued(&service);
  *decisions = service.Decisions();
  *estimate = service.Estimates();
}

// The same with snapshots only when asked: one after `snapshot_after` inputs.
void RunWithSnapshot(const std::string& path,
                     size_t snapshot_after,
                     std::vector<HypothesisDecision>* decisions,
                     std::vector<Service::SessionEstimate>* estimate) {
  DaemonJournal only_when_asked;
  only_when_asked.snapshot_every = 1 << 30;
  only_when_asked.snapshot_after_s = 0.0;
  RunJournaled(path, only_when_asked, /*batched=*/false, snapshot_after, decisions, estimate);
}

// Restarts from `path` (and its base and snapshot, if any); returns the recovery text. With
// `journal`, the service then takes it under `journal_options`, as irrrd does.
std::string Restart(const std::string& path,
                    const IrrrOptions& options,
                    std::vector<HypothesisDecision>* decisions,
                    std::vector<Service::SessionEstimate>* estimate,
                    Journal* journal = nullptr,
                    const DaemonJournal& journal_options = DaemonJournal()) {
  DaemonOptions daemon = FastResync();
  daemon.journal = journal_options;
  RecordingSink sink;
  Service service(daemon, options, &sink);
  Journal own;
  Journal* opened = journal != nullptr ? journal : &own;
  JournalRecovery recovery;
  REQUIRE(opened->Open(path, JournalSyncPolicy::kNever, &recovery).ok());
  REQUIRE(service.Recover(recovery, path).ok());
  if (journal != nullptr) service.SetJournal(journal);
  *decisions = service.Decisions();
  *estimate = service.Estimates();
  return service.CurrentStatus().recovery;
}

// Decided under `other` (alpha 0.99): what RunIncrementalIrrr says of the Intel case with those
// options, and thresholds other than those `decisions` were made at.
void CheckDecidedUnder(const IrrrOptions& other,
                       const std::vector<HypothesisDecision>& recovered,
                       const std::vector<HypothesisDecision>& decisions) {
  const Case& c = IntelCase();
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

TEST_CASE("A restart from a snapshot runs no step it covers and rebuilds the same state",
          "[reliability][slow]") {
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
    CheckSameState(recovered, recovered_estimate, decisions, estimate, kRestoredTolerance);
  }
  SECTION("a snapshot halfway: the second half is replayed with its steps") {
    RunWithSnapshot(path, c.messages.size() / 2, &decisions, &estimate);
    const std::string text = Restart(path, CaseOptions(), &recovered, &recovered_estimate);
    CHECK_THAT(text,
               Contains("then replayed " +
                        std::to_string(c.messages.size() - c.messages.size() / 2) + " inputs"));
    CheckSameState(recovered, recovered_estimate, decisions, estimate, kRestoredTolerance);
  }
  SECTION("a corrupt snapshot is not used: the whole journal is replayed") {
    RunWithSnapshot(path, c.messages.size() / 2, &decisions, &estimate);
    FlipByte(path + ".snapshot", 100);
    const std::string text = Restart(path, CaseOptions(), &recovered, &recovered_estimate);
    CHECK_THAT(text,
               !Contains("restored the snapshot") &&
                   Contains("replayed " + std::to_string(c.messages.size()) + " inputs"));
    CheckSameState(recovered, recovered_estimate, decisions, estimate, 0.0);
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
    CheckDecidedUnder(other, recovered, decisions);
  }
}

TEST_CASE(
    "A compacted journal restarts from its base, keeps its history when asked, and is "
    "refused without its base",
    "[reliability][slow]") {
  const Case& c = IntelCase();
  const std::string dir = TestDirectory("reliability_compact");
  const std::string path = dir + "/journal";
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    std::filesystem::remove(entry.path());
  }
  DaemonJournal options;
  options.snapshot_every = 1 << 30;  // the base alone
  options.snapshot_after_s = 0.0;
  options.compact_mb = 0.1;
  options.keep_compacted = true;
  std::vector<HypothesisDecision> decisions;
  std::vector<Service::SessionEstimate> estimate;
  RunJournaled(path, options, /*batched=*/false, 0, &decisions, &estimate);
  // The compacted records, kept as journal.<first>-<end>, in order.
  std::vector<std::pair<int64_t, std::string>> archives;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    const std::string name = entry.path().filename().string();
    if (name.rfind("journal.", 0) == 0 && std::isdigit(static_cast<unsigned char>(name[8]))) {
      archives.emplace_back(std::stoll(name.substr(8)), entry.path().string());
    }
  }
  std::sort(archives.begin(), archives.end());
  REQUIRE(archives.size() >= 3);
  JournalRecovery tail;
  {
    Journal journal;
    REQUIRE(journal.Open(path, JournalSyncPolicy::kNever, &tail).ok());
  }
  REQUIRE(tail.first_record > 0);
  std::vector<HypothesisDecision> recovered;
  std::vector<Service::SessionEstimate> recovered_estimate;

  SECTION("from the base and the journal after it: the same state") {
    const std::string text = Restart(path, CaseOptions(), &recovered, &recovered_estimate);
    CHECK_THAT(text,
               Contains("restored the base of the first " + std::to_string(tail.first_record) +
                        " inputs, then replayed " + std::to_string(tail.records.size())));
    CheckSameState(recovered, recovered_estimate, decisions, estimate, kRestoredTolerance);
  }
  SECTION("the archives and the journal hold every input: replayed whole, the same state") {
    const std::string whole = dir + "/whole";
    std::remove(whole.c_str());
    Journal journal;
    JournalRecovery none;
    REQUIRE(journal.Open(whole, JournalSyncPolicy::kNever, &none).ok());
    int64_t next = 0;
    for (const auto& [first, file] : archives) {
      INFO(file);
      Journal archive;
      JournalRecovery part;
      REQUIRE(archive.Open(file, JournalSyncPolicy::kNever, &part).ok());
      CHECK(part.first_record == next);
      REQUIRE(journal.Append(part.records).ok());
      next = archive.records();
    }
    CHECK(tail.first_record == next);
    REQUIRE(journal.Append(tail.records).ok());
    CHECK(journal.records() == static_cast<int64_t>(c.messages.size()));
    const std::string text = Restart(whole, CaseOptions(), &recovered, &recovered_estimate);
    CHECK_THAT(text,
               !Contains("base") && Contains("replayed " + std::to_string(c.messages.size())));
    CheckSameState(recovered, recovered_estimate, decisions, estimate, 0.0);
  }
  SECTION("a crash between the base and the journal's new start: the base, nothing replayed") {
    // The last compaction's archive is the journal as it was when its base was written.
    std::filesystem::copy_file(
        archives.back().second, path, std::filesystem::copy_options::overwrite_existing);
    Journal journal;
    const std::string text =
        Restart(path, CaseOptions(), &recovered, &recovered_estimate, &journal, options);
    CHECK_THAT(text,
               Contains("restored the base of the first " + std::to_string(tail.first_record) +
                        " inputs, then replayed 0 inputs"));
    CHECK(!recovered.empty());
    CHECK(recovered.size() <= decisions.size());
    // Given the journal, the service finishes the compaction: the journal starts after the base,
    // and its records are kept under the same name as before.
    CHECK(journal.first_record() == tail.first_record);
    CHECK(journal.size_bytes() == 20);
    int kept = 0;
    for (const auto& entry : std::filesystem::directory_iterator(dir)) {
      const std::string name = entry.path().filename().string();
      kept += name.rfind("journal.", 0) == 0 && std::isdigit(static_cast<unsigned char>(name[8]));
    }
    CHECK(kept == static_cast<int>(archives.size()));
  }
  SECTION("under other irrr options the base's inputs are decided again") {
    IrrrOptions other = CaseOptions();
    other.alpha = 0.99;
    const std::string text = Restart(path, other, &recovered, &recovered_estimate);
    CHECK_THAT(text, Contains("decided the inputs of the base (taken under other irrr options)"));
    CheckDecidedUnder(other, recovered, decisions);
  }
  SECTION("without its base, or with a corrupt one, the journal is refused with the reason") {
    const bool corrupt = GENERATE(false, true);
    if (corrupt) {
      FlipByte(path + ".base", 100);
    } else {
      std::remove((path + ".base").c_str());
    }
    RecordingSink sink;
    Service service(FastResync(), CaseOptions(), &sink);
    Journal journal;
    JournalRecovery recovery;
    REQUIRE(journal.Open(path, JournalSyncPolicy::kNever, &recovery).ok());
    const Status s = service.Recover(recovery, path);
    REQUIRE(!s.ok());
    CHECK_THAT(s.message(),
               Contains("starts at input " + std::to_string(tail.first_record)) &&
                   Contains(corrupt ? "fails its CRC" : "missing"));
  }
}

TEST_CASE("Snapshots are taken within a batch, by input count or by the steps' time",
          "[reliability][slow]") {
  const Case& c = IntelCase();
  const size_t total = c.messages.size();
  const std::string path = TestDirectory("reliability_snapshot_due") + "/journal";
  std::vector<HypothesisDecision> decisions;
  std::vector<Service::SessionEstimate> estimate;
  std::vector<HypothesisDecision> recovered;
  std::vector<Service::SessionEstimate> recovered_estimate;
  DaemonJournal options;
  SECTION("by count: the one snapshot falls 7 inputs before the end, inside the last batch") {
    options.snapshot_every = static_cast<int>(total) - 7;
    options.snapshot_after_s = 0.0;
    RunJournaled(path, options, /*batched=*/true, 0, &decisions, &estimate);
    const std::string text = Restart(path, CaseOptions(), &recovered, &recovered_estimate);
    CHECK_THAT(text,
               Contains("restored the snapshot of the first " + std::to_string(total - 7) +
                        " inputs, then replayed 7 inputs"));
  }
  SECTION("by the steps' time alone, input by input and in batches") {
    // The case's steps take far more than 0.05 s in all: snapshots are written by time alone.
    options.snapshot_every = 1 << 30;
    options.snapshot_after_s = 0.05;
    const bool batched = GENERATE(false, true);
    INFO("in batches: " << batched);
    RunJournaled(path, options, batched, 0, &decisions, &estimate);
    const std::string text = Restart(path, CaseOptions(), &recovered, &recovered_estimate);
    INFO(text);
    CHECK_THAT(text, Contains("restored the snapshot of the first"));
  }
  CheckSameState(recovered, recovered_estimate, decisions, estimate, kRestoredTolerance);
}

}  // namespace
}  // namespace irrr
