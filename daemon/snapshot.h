#ifndef IRRR_DAEMON_SNAPSHOT_H_
#define IRRR_DAEMON_SNAPSHOT_H_

// The daemon's snapshots: what the iRRR steps had computed at a point of the journal
// (IrrrStepState, core/irrr.h). A restart feeds the journal's inputs up to that point without
// running their steps (graph building only, fast), restores the snapshot, and runs the steps of
// the inputs after it: the same state as replaying everything, without re-deciding the past.
//
// File (next to the journal, "<journal>.snapshot"; replaced atomically: written to ".tmp",
// synced, renamed):
//   8 bytes "IRRRSNP6" | uint32 body length | uint32 CRC-32 (zlib) of the body | body
// The body is a little-endian sequence written by SnapshotWriter and read back, bounds-checked,
// by SnapshotReader; what it holds is the service's business (service_recovery.cc).
//
// A base ("<journal>.base", the same layout beginning with "IRRRBAS1") holds the whole state at a
// point of the journal, so that the journal can start again after it (compaction): an Irrr's
// inputs in the order it took them (Inputs: a fresh Irrr fed them rebuilds its graph and clusters)
// besides its step state, and the service's own tables.

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "core/irrr.h"
#include "core/status.h"
#include "daemon/common/irrr_config.h"

namespace irrr {

class SnapshotWriter {
 public:
  void I64(int64_t v);
  void F64(double v);
  void String(const std::string& s);
  void Ints(const std::vector<int>& v);
  template <class Pose>
  void PoseValue(const Pose& pose);
  template <class Pose>
  void StepState(const IrrrStepState<Pose>& state);
  // What `irrr` was fed (Irrr::Arrivals), each input with its data, information as given.
  template <class Pose>
  void Inputs(const Irrr<Pose>& irrr);

  const std::vector<uint8_t>& bytes() const { return bytes_; }

 private:
  template <class Pose>
  void InformationValue(const typename Pose::Matrix& information);

  std::vector<uint8_t> bytes_;
};

// Every getter returns false (and leaves the reader failed) when the body ends too soon or holds
// a count that cannot fit in what is left.
class SnapshotReader {
 public:
  explicit SnapshotReader(const std::vector<uint8_t>& body) : body_(body) {}

  bool I64(int64_t* v);
  bool F64(double* v);
  bool String(std::string* s);
  bool Ints(std::vector<int>* v);
  template <class Pose>
  bool PoseValue(Pose* pose);
  template <class Pose>
  bool StepState(IrrrStepState<Pose>* state);
  // Feeds the inputs SnapshotWriter::Inputs wrote to `irrr`, fresh (nothing fed yet), calling
  // `after_each` (if any: the steps that became due) after each. False when they do not decode or
  // `irrr` refuses one (it is then unusable).
  template <class Pose>
  bool FeedInputs(Irrr<Pose>* irrr, const std::function<void()>& after_each = nullptr);

  bool at_end() const { return at_ == body_.size(); }

 private:
  bool Int(int* v);
  bool Count(size_t min_bytes_each, size_t* count);
  template <class Pose>
  bool InformationValue(typename Pose::Matrix* information);

  const std::vector<uint8_t>& body_;
  size_t at_ = 0;
  bool failed_ = false;
};

enum class SnapshotKind { kSnapshot, kBase };

// Writes `body` to `path` atomically. `sync` kNever skips the fsyncs (the rename is still atomic
// for a process crash).
Status WriteSnapshotFile(const std::string& path,
                         const std::vector<uint8_t>& body,
                         JournalSyncPolicy sync,
                         SnapshotKind kind = SnapshotKind::kSnapshot);
// Reads the body back; `*exists` false (and ok) when there is no file.
Status ReadSnapshotFile(const std::string& path,
                        std::vector<uint8_t>* body,
                        bool* exists,
                        SnapshotKind kind = SnapshotKind::kSnapshot);

template <>
void SnapshotWriter::PoseValue(const Pose2& pose);
template <>
void SnapshotWriter::PoseValue(const Pose3& pose);
template <>
bool SnapshotReader::PoseValue(Pose2* pose);
template <>
bool SnapshotReader::PoseValue(Pose3* pose);
extern template void SnapshotWriter::StepState(const IrrrStepState<Pose2>&);
extern template void SnapshotWriter::StepState(const IrrrStepState<Pose3>&);
extern template bool SnapshotReader::StepState(IrrrStepState<Pose2>*);
extern template bool SnapshotReader::StepState(IrrrStepState<Pose3>*);
extern template void SnapshotWriter::Inputs(const Irrr<Pose2>&);
extern template void SnapshotWriter::Inputs(const Irrr<Pose3>&);
extern template bool SnapshotReader::FeedInputs(Irrr<Pose2>*, const std::function<void()>&);
extern template bool SnapshotReader::FeedInputs(Irrr<Pose3>*, const std::function<void()>&);

}  // namespace irrr

#endif  // IRRR_DAEMON_SNAPSHOT_H_
