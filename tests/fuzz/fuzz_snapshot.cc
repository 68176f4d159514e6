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

namespace {

// A small Irrr fed inputs without running their steps, as a restart has it: two sessions, a few
// poses, two loops (one cluster per session pair).
template <class Pose>
irrr::Irrr<Pose>& Fed() {
  static irrr::Irrr<Pose>* irrr = [] {
    irrr::IrrrOptions options;
    options.cluster_gap = 2.0;
    auto* fed = new irrr::Irrr<Pose>(options);
    int a = -1;
    int b = -1;
    fed->AddSession(1, &a);
    fed->AddSession(2, &b);
    const typename Pose::Matrix information = Pose::Matrix::Identity();
    const Pose step = Pose::Exp(Pose::Tangent::Constant(0.1));
    std::vector<int> va(5);
    std::vector<int> vb(5);
    for (int k = 0; k < 5; ++k) {
      fed->AddPose(a, k, k, k == 0 ? nullptr : &step, k == 0 ? nullptr : &information, &va[k]);
      fed->AddPose(b, 10 + k, k, k == 0 ? nullptr : &step, k == 0 ? nullptr : &information, &vb[k]);
    }
    fed->AddLoop(va[4], va[0], Pose(), information, nullptr);
    fed->AddLoop(vb[3], va[1], Pose(), information, nullptr);
    fed->Flush();
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
  const bool restored = Fed<irrr::Pose2>().RestoreStepState(se2).ok() &&
                        Fed<irrr::Pose3>().RestoreStepState(se3).ok();
  (void)restored;
  // Inputs: each one the fresh Irrr takes, or refuses (the feed then stops).
  irrr::IrrrOptions options;
  options.cluster_gap = 2.0;
  irrr::Irrr<irrr::Pose2> fresh2(options);
  irrr::Irrr<irrr::Pose3> fresh3(options);
  if (reader.FeedInputs(&fresh2)) reader.FeedInputs(&fresh3);
  return 0;
}
