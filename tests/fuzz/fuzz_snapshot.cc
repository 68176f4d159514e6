// libFuzzer target: a daemon snapshot's body (daemon/snapshot.h) read back and restored into an
// Irrr (core/irrr.h RestoreStepState), then, as a base holds them, an SE(2) and an SE(3) Irrr's
// inputs fed to fresh ones (SnapshotReader::FeedInputs). A file that fails its CRC never gets this
// far, but a snapshot or base written by another version, or a disk that returns other bytes with
// a valid CRC, must be refused, never crash the daemon.

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "core/irrr.h"
#include "daemon/snapshot.h"
#include "tests/fuzz/two_sessions.h"

namespace {

// The two-session graph fed without running its steps, as a restart has it.
template <class Pose>
irrr::Irrr<Pose>& Fed() {
  static irrr::Irrr<Pose>* irrr = [] {
    auto* fed = new irrr::Irrr<Pose>(irrr::fuzz::TwoSessionsOptions());
    irrr::fuzz::FeedTwoSessions(fed);
    return fed;
  }();
  return *irrr;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::vector<uint8_t> body(data, data + size);
  irrr::SnapshotReader reader(body);
  std::string options;
  int64_t records = 0;
  std::vector<int> anchors;
  irrr::IrrrStepState<irrr::Pose2> se2;
  irrr::IrrrStepState<irrr::Pose3> se3;
  if (!reader.String(&options) || !reader.I64(&records) || !reader.Ints(&anchors) ||
      !reader.StepState(&se2) || !reader.StepState(&se3)) {
    return 0;
  }
  // Whatever decoded either fits the Irrr or is refused with a reason.
  if (Fed<irrr::Pose2>().RestoreStepState(se2).ok()) {
    static_cast<void>(Fed<irrr::Pose3>().RestoreStepState(se3));
  }
  // Inputs: each one the fresh Irrr takes, or refuses (the feed then stops).
  irrr::Irrr<irrr::Pose2> fresh2(irrr::fuzz::TwoSessionsOptions());
  irrr::Irrr<irrr::Pose3> fresh3(irrr::fuzz::TwoSessionsOptions());
  if (reader.FeedInputs(&fresh2)) reader.FeedInputs(&fresh3);
  return 0;
}
