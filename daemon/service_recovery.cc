// Service, recovery: every input kept in the journal before it is applied; at start the journal
// replayed, from a snapshot of the steps' state when one fits (snapshot.h); snapshots written
// every daemon.journal.snapshot_every inputs and at a clean stop (service_state.h).

#include <chrono>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include <fmt/core.h>
#include <spdlog/spdlog.h>

#include "daemon/service_state.h"
#include "daemon/snapshot.h"

namespace irrr {

std::string Service::State::OptionsText() const { return IrrrOptionsToJson(options).dump(); }

Status Service::State::WriteSnapshot(int64_t records, uint32_t crc) {
  SnapshotWriter w;
  w.String(OptionsText());
  w.I64(records);
  w.I64(crc);
  w.I64(solution_id);
  {
    std::lock_guard<std::mutex> lock(stats_mutex);
    w.I64(stats.n_steps);
  }
  w.Ints(se2.anchor);
  w.StepState(se2.irrr.StepState());
  w.Ints(se3.anchor);
  w.StepState(se3.irrr.StepState());
  if (Status s = WriteSnapshotFile(snapshot_path, w.bytes(), daemon.journal.fsync); !s.ok()) {
    return s;
  }
  snapshot_at = records;
  steps_s_since_snapshot = 0.0;
  snapshot_bytes = static_cast<int64_t>(w.bytes().size());
  return Status::Ok();
}

bool Service::State::LoadSnapshot(const std::string& path,
                                  const JournalRecovery& recovery,
                                  Snapshot* out,
                                  std::string* why) const {
  std::vector<uint8_t> body;
  bool exists = false;
  if (Status s = ReadSnapshotFile(path, &body, &exists); !s.ok() || !exists) {
    *why = s.ok() ? "" : s.message();
    return false;
  }
  SnapshotReader r(body);
  Snapshot& snap = *out;
  if (!r.String(&snap.options) || !r.I64(&snap.records) || !r.I64(&snap.journal_crc) ||
      !r.I64(&snap.solution_id) || !r.I64(&snap.steps) || !r.Ints(&snap.anchor_se2) ||
      !r.StepState(&snap.se2) || !r.Ints(&snap.anchor_se3) || !r.StepState(&snap.se3) ||
      !r.at_end()) {
    *why = path + ": its body does not decode";
    return false;
  }
  if (snap.options != OptionsText()) {
    *why = path + " was taken under other irrr options: the journal is decided again under these";
    return false;
  }
  if (snap.records < 0 || static_cast<size_t>(snap.records) > recovery.records.size() ||
      JournalCrc(recovery.records, static_cast<size_t>(snap.records)) !=
          static_cast<uint32_t>(snap.journal_crc)) {
    *why = path + " covers " + std::to_string(snap.records) +
           " journal records that are not those of the journal (" +
           std::to_string(recovery.records.size()) + " records)";
    return false;
  }
  return true;
}

Status Service::State::RestoreSnapshot(Snapshot snap) {
  if (snap.anchor_se2.size() != se2.sessions.size() ||
      snap.anchor_se3.size() != se3.sessions.size()) {
    return Status::Error("its sessions are not the journal's");
  }
  if (Status s = se2.irrr.RestoreStepState(std::move(snap.se2)); !s.ok()) return s;
  if (Status s = se3.irrr.RestoreStepState(std::move(snap.se3)); !s.ok()) return s;
  se2.anchor = std::move(snap.anchor_se2);
  se3.anchor = std::move(snap.anchor_se3);
  solution_id = snap.solution_id;
  snapshot_at = snap.records;
  std::lock_guard<std::mutex> lock(stats_mutex);
  stats.n_steps = snap.steps;
  return Status::Ok();
}

int64_t Service::State::Replay(const JournalRecovery& recovery,
                               size_t begin,
                               size_t end,
                               const std::string& path,
                               std::map<std::string, int64_t>* senders_next) {
  int64_t applied = 0;
  for (size_t k = begin; k < end; ++k) {
    const JournalRecord& record = recovery.records[k];
    Input input;
    if (!DecodeInput(
            record.kind, record.bytes.data(), static_cast<int>(record.bytes.size()), &input)) {
      spdlog::error("journal {}: record {} does not decode (skipped)", path, k);
      continue;
    }
    input.received_utime = record.received_utime;
    int64_t& next = (*senders_next)[input.header().sender];
    next = std::max(next, input.header().seq + 1);
    Apply(input);
    ++applied;
  }
  return applied;
}

void Service::SetJournal(Journal* journal) {
  state_->journal = journal;
  state_->snapshot_path = journal != nullptr && state_->daemon.journal.snapshot_every > 0
                              ? journal->path() + ".snapshot"
                              : "";
}

Status Service::WriteSnapshot() {
  State& st = *state_;
  if (st.journal == nullptr) return st.SnapshotAt(0, 0);
  return st.SnapshotAt(st.journal->records(), st.journal->crc());
}

Status Service::State::SnapshotAt(int64_t records, uint32_t crc) {
  if (journal == nullptr || snapshot_path.empty()) {
    return Status::Error("snapshots are off (no journal, or daemon.journal.snapshot_every 0)");
  }
  {
    std::lock_guard<std::mutex> lock(stats_mutex);
    if (!journal_error.empty()) {
      return Status::Error("the journal lacks inputs that were applied (" + journal_error +
                           "): no snapshot would match it");
    }
  }
  const auto start = std::chrono::steady_clock::now();
  if (Status s = WriteSnapshot(records, crc); !s.ok()) return s;
  spdlog::info(
      "snapshot of the first {} inputs ({:.2f} MB) written to {} in {:.1f} ms",
      records,
      1e-6 * static_cast<double>(snapshot_bytes),
      snapshot_path,
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
  return Status::Ok();
}

void Service::Recover(const JournalRecovery& recovery, const std::string& path) {
  const auto start = std::chrono::steady_clock::now();
  state_->replaying = true;
  std::map<std::string, int64_t> next_seq;
  // A snapshot spares the steps of the inputs it covers: they are fed without them, then it
  // is restored; only the inputs after it run their steps.
  size_t from = 0;
  std::string snapshot_note;
  {
    State::Snapshot snapshot;
    std::string why;
    const std::string snapshot_path = path + ".snapshot";
    if (state_->LoadSnapshot(snapshot_path, recovery, &snapshot, &why)) {
      const size_t covered = static_cast<size_t>(snapshot.records);
      state_->run_steps = false;
      state_->Replay(recovery, 0, covered, path, &next_seq);
      state_->run_steps = true;
      if (Status s = state_->RestoreSnapshot(std::move(snapshot)); s.ok()) {
        from = covered;
        snapshot_note =
            "restored the snapshot of the first " + std::to_string(covered) + " inputs, then ";
      } else {
        why = snapshot_path + ": " + s.message();
        // Start again from nothing, without it.
        const State& st = *state_;
        auto fresh = std::make_unique<State>(st.daemon, st.options, st.sink);
        fresh->journal = st.journal;
        fresh->snapshot_path = st.snapshot_path;
        state_ = std::move(fresh);
        state_->replaying = true;
        next_seq.clear();
      }
    }
    if (!why.empty()) spdlog::warn("snapshot not used: {}", why);
  }
  State& st = *state_;
  const int64_t applied = st.Replay(recovery, from, recovery.records.size(), path, &next_seq);
  st.replaying = false;
  {
    std::lock_guard<std::mutex> lock(st.sequencer_mutex);
    for (const auto& [sender, next] : next_seq) st.sequencer.Resume(sender, next);
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::string text = snapshot_note + "replayed " + std::to_string(applied) + " inputs from " +
                     path + " in " + fmt::format("{:.2f}", seconds) + " s";
  if (recovery.dropped_bytes > 0) {
    text += "; dropped " + std::to_string(recovery.dropped_bytes) + " bytes at its end (" +
            recovery.dropped_reason + ")";
    spdlog::warn("journal {}: dropped {} bytes at offset {}: {} (a write torn by a crash)",
                 path,
                 recovery.dropped_bytes,
                 recovery.valid_bytes,
                 recovery.dropped_reason);
  }
  spdlog::info("journal {}: {}; {} steps, {} hypotheses",
               path,
               text,
               st.stats.n_steps,
               st.hypothesis_order.size());
  {
    std::lock_guard<std::mutex> lock(st.stats_mutex);
    st.stats.n_recovered = static_cast<int64_t>(recovery.records.size());
    st.stats.recovery = text;
  }
  st.PublishComplete();
}

}  // namespace irrr
