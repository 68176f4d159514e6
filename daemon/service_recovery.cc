// Service, recovery: every input kept in the journal before it is applied; at start the journal
// replayed, from the base when it was compacted and from a snapshot of the steps' state when one
// fits (snapshot.h); snapshots written every daemon.journal.snapshot_every inputs and at a clean
// stop, the base when the journal outgrows daemon.journal.compact_mb (service_state.h).

#include <chrono>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include <fmt/core.h>
#include <spdlog/spdlog.h>

#include "daemon/service_state.h"
#include "daemon/snapshot.h"

namespace irrr {
namespace {

// Whether the journal holds the end of the first `records` records and their CRC is `crc`.
bool Covers(const JournalRecovery& journal, int64_t records, int64_t crc) {
  return records >= journal.first_record &&
         records - journal.first_record <= static_cast<int64_t>(journal.records.size()) &&
         JournalCrc(journal, records) == static_cast<uint32_t>(crc);
}

// "records F to E": what the journal holds, for the reasons a snapshot or base is not used.
std::string RecordRange(const JournalRecovery& journal) {
  return "records " + std::to_string(journal.first_record) + " to " +
         std::to_string(journal.first_record + static_cast<int64_t>(journal.records.size()));
}

}  // namespace

std::string Service::State::OptionsText() const { return IrrrOptionsToJson(options).dump(); }

void Service::State::WriteHeader(int64_t records, uint32_t crc, SnapshotWriter* w) const {
  w->String(OptionsText());
  w->I64(records);
  w->I64(crc);
  w->I64(solution_id);
  std::lock_guard<std::mutex> lock(stats_mutex);
  w->I64(stats.n_steps);
}

bool Service::State::ReadHeader(SnapshotReader* r, Snapshot* snap) {
  return r->String(&snap->options) && r->I64(&snap->records) && r->I64(&snap->journal_crc) &&
         r->I64(&snap->solution_id) && r->I64(&snap->steps);
}

Status Service::State::WriteSnapshot(int64_t records, uint32_t crc) {
  SnapshotWriter w;
  WriteHeader(records, crc, &w);
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
  if (!ReadHeader(&r, &snap) || !r.Ints(&snap.anchor_se2) || !r.StepState(&snap.se2) ||
      !r.Ints(&snap.anchor_se3) || !r.StepState(&snap.se3) || !r.at_end()) {
    *why = path + ": its body does not decode";
    return false;
  }
  if (snap.options != OptionsText()) {
    *why = path + " was taken under other irrr options: the journal is decided again under these";
    return false;
  }
  if (!Covers(recovery, snap.records, snap.journal_crc)) {
    *why = path + " covers " + std::to_string(snap.records) +
           " journal records that are not those of the journal (" + RecordRange(recovery) + ")";
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
                               const std::string& path) {
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
    Journaled(input);
    Apply(input);
    ++applied;
  }
  return applied;
}

void Service::State::Journaled(const Input& input) {
  int64_t& next = journaled_next[input.header().sender];
  next = std::max(next, input.header().seq + 1);
}

void Service::SetJournal(Journal* journal) {
  state_->journal = journal;
  state_->snapshot_path = journal != nullptr && state_->daemon.journal.snapshot_every > 0
                              ? journal->path() + ".snapshot"
                              : "";
  state_->base_path =
      journal != nullptr && state_->daemon.journal.compact_mb > 0 ? journal->path() + ".base" : "";
  state_->compact_at_bytes = static_cast<int64_t>(state_->daemon.journal.compact_mb * 1e6);
  if (journal == nullptr) return;
  // A compaction a crash interrupted (the base written, the journal not started again after it):
  // finished, so that the journal never holds records the base covers.
  State& st = *state_;
  if (st.base_at > journal->first_record() && st.base_at == journal->records()) {
    if (Status s = journal->Compact(st.ArchiveName()); !s.ok()) {
      spdlog::error("journal compaction: {}", s.message());
    } else {
      spdlog::info("journal {}: the compaction at input {} finished", journal->path(), st.base_at);
    }
  }
  // A journal recovered whole (every record applied) that is over the bound already.
  st.CompactIfDue();
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

Status Service::Recover(const JournalRecovery& recovery, const std::string& path) {
  const auto start = std::chrono::steady_clock::now();
  const std::string base_path = path + ".base";
  const bool compacted = recovery.first_record > 0;
  auto fresh = [this] {
    const State& st = *state_;
    auto state = std::make_unique<State>(st.daemon, st.options, st.sink);
    state->journal = st.journal;
    state->snapshot_path = st.snapshot_path;
    state->base_path = st.base_path;
    state->compact_at_bytes = st.compact_at_bytes;
    state_ = std::move(state);
    state_->replaying = true;
  };
  // The base (after a compaction): the whole state at a record of the journal. The journal's
  // records before it are fed no more.
  State::Snapshot base_steps;
  size_t base_from = 0;
  bool decided_again = false;
  auto load_base = [&](std::string* why) {
    if (!state_->LoadBase(base_path, recovery, &base_steps, &decided_again, why)) return false;
    base_from = static_cast<size_t>(base_steps.records - recovery.first_record);
    state_->base_at = base_steps.records;
    return true;
  };
  state_->replaying = true;
  std::string note;
  std::string why;
  bool has_base = load_base(&why);
  if (!has_base) {
    if (compacted) {
      return Status::Error(path + " starts at input " + std::to_string(recovery.first_record) +
                           ", after a base that cannot be used (" +
                           (why.empty() ? base_path + ": missing" : why) +
                           "): the inputs before it are gone. Move the journal and its base "
                           "away to start a new map");
    }
    if (!why.empty()) {
      spdlog::warn("base not used: {}", why);
      fresh();
    }
  }
  if (has_base) {
    note = (decided_again ? "decided the inputs of the base (taken under other irrr options) "
                            "again, the first "
                          : "restored the base of the first ") +
           std::to_string(base_steps.records) + " inputs, ";
  }
  // A snapshot at or after the base spares the steps of the inputs it covers: they are fed
  // without them, then it is restored; only the inputs after it run their steps.
  size_t from = base_from;
  bool restored = false;
  {
    State::Snapshot snapshot;
    const std::string snapshot_path = path + ".snapshot";
    why.clear();
    if (state_->LoadSnapshot(snapshot_path, recovery, &snapshot, &why)) {
      const size_t covered = static_cast<size_t>(snapshot.records - recovery.first_record);
      if (covered >= base_from) {
        state_->run_steps = false;
        state_->Replay(recovery, base_from, covered, path);
        state_->run_steps = true;
        if (Status s = state_->RestoreSnapshot(std::move(snapshot)); s.ok()) {
          from = covered;
          restored = true;
          note += "restored the snapshot of the first " +
                  std::to_string(recovery.first_record + static_cast<int64_t>(covered)) +
                  " inputs, ";
        } else {
          why = snapshot_path + ": " + s.message();
          // Start again without it.
          fresh();
          if (has_base) IRRR_CHECK(load_base(&why));
        }
      }
    }
    if (!why.empty()) spdlog::warn("snapshot not used: {}", why);
  }
  State& st = *state_;
  if (has_base && !restored && !decided_again) {
    if (Status s = st.RestoreSnapshot(std::move(base_steps)); !s.ok()) {
      return Status::Error(base_path + ": its step state does not fit its inputs: " + s.message());
    }
  }
  const double restored_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const int64_t applied = st.Replay(recovery, from, recovery.records.size(), path);
  st.replaying = false;
  {
    std::lock_guard<std::mutex> lock(st.sequencer_mutex);
    for (const auto& [sender, next] : st.journaled_next) st.sequencer.Resume(sender, next);
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::string text = (note.empty() ? "" : note + "then ") + "replayed " + std::to_string(applied) +
                     " inputs from " + path + " in " + fmt::format("{:.2f}", seconds) + " s";
  if (!note.empty()) text += fmt::format(" ({:.2f} s before the steps)", restored_s);
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
  return Status::Ok();
}

// ---- The base and compaction ----

template <class Pose>
void Service::State::WriteEngine(const Engine<Pose>& engine, SnapshotWriter* w) const {
  w->I64(static_cast<int64_t>(engine.sessions.size()));
  for (const auto& info : engine.sessions) {
    w->I64(info.name.first);
    w->I64(info.name.second);
    w->I64(info.order);
    w->I64(info.first_key);
  }
  w->I64(static_cast<int64_t>(engine.odom_pose.size()));
  for (const Pose& pose : engine.odom_pose) w->PoseValue(pose);
  w->Ints(engine.anchor);
  w->I64(static_cast<int64_t>(engine.hypothesis_of_edge.size()));
  for (const auto& [edge, h] : engine.hypothesis_of_edge) {
    w->I64(edge);
    w->String(h.sender);
    for (int64_t v : {h.id,
                      int64_t{h.robot_from},
                      int64_t{h.session_from},
                      h.key_from,
                      int64_t{h.robot_to},
                      int64_t{h.session_to},
                      h.key_to}) {
      w->I64(v);
    }
  }
  w->Inputs(engine.irrr);
  w->StepState(engine.irrr.StepState());
}

Status Service::State::WriteBase(int64_t records, uint32_t crc) {
  SnapshotWriter w;
  WriteHeader(records, crc, &w);
  w.I64(next_vertex_id);
  w.I64(static_cast<int64_t>(journaled_next.size()));
  for (const auto& [sender, next] : journaled_next) {
    w.String(sender);
    w.I64(next);
  }
  WriteEngine(se2, &w);
  WriteEngine(se3, &w);
  w.I64(static_cast<int64_t>(hypothesis_order.size()));
  for (const HypothesisRef& ref : hypothesis_order) {
    w.I64(ref.dim);
    w.I64(ref.edge);
  }
  w.I64(static_cast<int64_t>(parked.size()));
  for (const auto& [key, inputs] : parked) {
    w.I64(std::get<0>(key));
    w.I64(std::get<1>(key));
    w.I64(std::get<2>(key));
    w.I64(static_cast<int64_t>(inputs.size()));
    for (const Input& input : inputs) {
      w.I64(JournalKind(input.kind));
      w.I64(input.received_utime);
      w.String(std::string(input.bytes.begin(), input.bytes.end()));
    }
  }
  return WriteSnapshotFile(base_path, w.bytes(), daemon.journal.fsync, SnapshotKind::kBase);
}

template <class Pose>
bool Service::State::ReadEngine(SnapshotReader* r,
                                Engine<Pose>* engine,
                                IrrrStepState<Pose>* steps,
                                bool decide_again) {
  int64_t n = 0;
  if (!r->I64(&n) || n < 0 || n > daemon.limits.max_sessions) return false;
  engine->sessions.resize(static_cast<size_t>(n));
  for (auto& info : engine->sessions) {
    int64_t robot = 0;
    int64_t session = 0;
    int64_t order = 0;
    if (!r->I64(&robot) || !r->I64(&session) || !r->I64(&order) || !r->I64(&info.first_key)) {
      return false;
    }
    info.name = {static_cast<int32_t>(robot), static_cast<int32_t>(session)};
    info.order = static_cast<int>(order);
  }
  if (!r->I64(&n) || n < 0 || n > daemon.limits.max_keyframes) return false;
  engine->odom_pose.resize(static_cast<size_t>(n));
  for (Pose& pose : engine->odom_pose) {
    if (!r->PoseValue(&pose)) return false;
  }
  if (!r->Ints(&engine->anchor) || !r->I64(&n) || n < 0 || n > daemon.limits.max_hypotheses) {
    return false;
  }
  for (int64_t k = 0; k < n; ++k) {
    int64_t edge = 0;
    Hypothesis h;
    int64_t v[6];
    if (!r->I64(&edge) || !r->String(&h.sender) || !r->I64(&h.id)) return false;
    for (int64_t& x : v) {
      if (!r->I64(&x)) return false;
    }
    h.robot_from = static_cast<int32_t>(v[0]);
    h.session_from = static_cast<int32_t>(v[1]);
    h.key_from = v[2];
    h.robot_to = static_cast<int32_t>(v[3]);
    h.session_to = static_cast<int32_t>(v[4]);
    h.key_to = v[5];
    engine->hypothesis_of_edge.emplace(static_cast<int>(edge), h);
  }
  std::function<void()> steps_due;
  if (decide_again) {
    // Decided again from the start: each session in its own map, as it arrived.
    engine->anchor.resize(engine->sessions.size());
    for (size_t s = 0; s < engine->sessions.size(); ++s) {
      engine->anchor[s] = engine->sessions[s].order;
    }
    steps_due = [this, engine] { RunSteps(*engine, 0); };
  }
  if (!r->FeedInputs(&engine->irrr, steps_due) || !r->StepState(steps)) return false;
  // What the tables name must be in the graph the inputs built.
  const PoseGraph<Pose>& graph = engine->irrr.graph();
  if (static_cast<int>(engine->sessions.size()) != graph.num_sessions() ||
      engine->anchor.size() != engine->sessions.size() ||
      static_cast<int>(engine->odom_pose.size()) != graph.num_vertices()) {
    return false;
  }
  for (const auto& [edge, unused] : engine->hypothesis_of_edge) {
    if (edge < 0 || edge >= graph.num_edges() || graph.edge(edge).kind != EdgeKind::kLoop) {
      return false;
    }
  }
  for (size_t s = 0; s < engine->sessions.size(); ++s) {
    const SessionName& name = engine->sessions[s].name;
    if (!sessions.emplace(name, SessionRef{WireDim<Pose>(), static_cast<int>(s)}).second) {
      return false;
    }
    num_keyframes += static_cast<int64_t>(graph.session(static_cast<int>(s)).vertices.size());
  }
  for (const auto& [edge, h] : engine->hypothesis_of_edge) {
    if (!hypotheses.emplace(std::make_pair(h.sender, h.id), HypothesisRef{WireDim<Pose>(), edge})
             .second) {
      return false;
    }
  }
  return true;
}

bool Service::State::LoadBase(const std::string& path,
                              const JournalRecovery& recovery,
                              Snapshot* steps,
                              bool* decided_again,
                              std::string* why) {
  std::vector<uint8_t> body;
  bool exists = false;
  if (Status s = ReadSnapshotFile(path, &body, &exists, SnapshotKind::kBase); !s.ok() || !exists) {
    *why = s.ok() ? "" : s.message();
    return false;
  }
  SnapshotReader r(body);
  Snapshot& snap = *steps;
  if (!ReadHeader(&r, &snap)) {
    *why = path + ": its body does not decode";
    return false;
  }
  *decided_again = snap.options != OptionsText();
  if (!Covers(recovery, snap.records, snap.journal_crc)) {
    *why = path + " holds the first " + std::to_string(snap.records) +
           " inputs, which do not end in the journal (" + RecordRange(recovery) + ")";
    return false;
  }
  auto decoded = [&] {
    int64_t n = 0;
    if (!r.I64(&next_vertex_id) || !r.I64(&n) || n < 0) return false;
    for (int64_t k = 0; k < n; ++k) {
      std::string sender;
      int64_t next = 0;
      if (!r.String(&sender) || !r.I64(&next)) return false;
      journaled_next[sender] = next;
    }
    // The base's steps ran under other options: its inputs' steps run again under these.
    if (!ReadEngine(&r, &se2, &snap.se2, *decided_again) ||
        !ReadEngine(&r, &se3, &snap.se3, *decided_again)) {
      return false;
    }
    snap.anchor_se2 = se2.anchor;
    snap.anchor_se3 = se3.anchor;
    num_sessions = static_cast<int>(se2.sessions.size() + se3.sessions.size());
    session_names.assign(static_cast<size_t>(num_sessions), SessionName{});
    auto name_sessions = [this](const auto& infos) {
      for (const auto& info : infos) {
        if (info.order < 0 || info.order >= num_sessions) return false;
        session_names[static_cast<size_t>(info.order)] = info.name;
      }
      return true;
    };
    if (!name_sessions(se2.sessions) || !name_sessions(se3.sessions)) return false;
    if (!r.I64(&n) || n != static_cast<int64_t>(hypotheses.size())) return false;
    for (int64_t k = 0; k < n; ++k) {
      int64_t dim = 0;
      int64_t edge = 0;
      if (!r.I64(&dim) || !r.I64(&edge)) return false;
      const auto& known =
          dim == keyframe_t::DIM_SE2 ? se2.hypothesis_of_edge : se3.hypothesis_of_edge;
      if (known.count(static_cast<int>(edge)) == 0) return false;
      hypothesis_order.push_back(HypothesisRef{static_cast<int8_t>(dim), static_cast<int>(edge)});
    }
    if (!r.I64(&n) || n < 0) return false;
    for (int64_t k = 0; k < n; ++k) {
      int64_t robot = 0;
      int64_t session = 0;
      int64_t key = 0;
      int64_t count = 0;
      if (!r.I64(&robot) || !r.I64(&session) || !r.I64(&key) || !r.I64(&count) || count < 0) {
        return false;
      }
      auto& inputs =
          parked[KeyName{static_cast<int32_t>(robot), static_cast<int32_t>(session), key}];
      for (int64_t i = 0; i < count; ++i) {
        int64_t kind = 0;
        Input input;
        std::string bytes;
        if (!r.I64(&kind) || !r.I64(&input.received_utime) || !r.String(&bytes) || kind < 0 ||
            kind > JournalRecord::kSession ||
            !DecodeInput(static_cast<JournalRecord::Kind>(kind),
                         reinterpret_cast<const uint8_t*>(bytes.data()),
                         static_cast<int>(bytes.size()),
                         &input)) {
          return false;
        }
        inputs.push_back(std::move(input));
        ++num_parked;
      }
    }
    return r.at_end();
  };
  if (!decoded()) {
    *why = path + ": its body does not decode";
    return false;
  }
  std::lock_guard<std::mutex> lock(stats_mutex);
  stats.n_keyframes = num_keyframes;
  stats.n_sessions = num_sessions;
  stats.n_hypotheses = static_cast<int64_t>(hypothesis_order.size());
  stats.n_parked = static_cast<int32_t>(num_parked);
  return true;
}

std::string Service::State::ArchiveName() const {
  if (!daemon.journal.keep_compacted) return "";
  return journal->path() + "." + std::to_string(journal->first_record()) + "-" +
         std::to_string(journal->records());
}

void Service::State::CompactIfDue() {
  if (journal == nullptr || base_path.empty() || journal->size_bytes() < compact_at_bytes) return;
  {
    std::lock_guard<std::mutex> lock(stats_mutex);
    if (!journal_error.empty()) return;  // the journal lacks inputs: no base would match it
  }
  const auto start = std::chrono::steady_clock::now();
  const int64_t records = journal->records();
  const double journal_mb = 1e-6 * static_cast<double>(journal->size_bytes());
  const std::string archive = ArchiveName();
  Status s = WriteBase(records, journal->crc());
  if (s.ok()) s = journal->Compact(archive);
  if (!s.ok()) {
    // Tried again once the journal has grown as much again.
    compact_at_bytes =
        journal->size_bytes() + static_cast<int64_t>(daemon.journal.compact_mb * 1e6);
    spdlog::error("journal compaction: {} (the journal goes on growing)", s.message());
    return;
  }
  // The base holds the step state too.
  base_at = records;
  snapshot_at = records;
  steps_s_since_snapshot = 0.0;
  spdlog::info(
      "journal {} compacted at input {} ({:.1f} MB): the whole state written to {} in "
      "{:.0f} ms{}",
      journal->path(),
      records,
      journal_mb,
      base_path,
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count(),
      archive.empty() ? "" : "; its records kept as " + archive);
}

}  // namespace irrr
