#ifndef IRRR_TESTS_FUZZ_TWO_SESSIONS_H_
#define IRRR_TESTS_FUZZ_TWO_SESSIONS_H_

// The small graph of fuzz_snapshot and its seeds: two sessions of five poses each (interleaved),
// a loop within the first and one between them (one cluster per session pair), then a flush.

#include <vector>

#include "core/irrr.h"

namespace irrr {
namespace fuzz {

inline IrrrOptions TwoSessionsOptions() {
  IrrrOptions options;
  options.cluster_gap = 2.0;
  return options;
}

// Feeds the graph to `irrr` (fresh), without running steps.
template <class Pose>
void FeedTwoSessions(Irrr<Pose>* irrr) {
  int a = -1;
  int b = -1;
  irrr->AddSession(1, &a);
  irrr->AddSession(2, &b);
  const typename Pose::Matrix information = Pose::Matrix::Identity();
  const Pose step = Pose::Exp(Pose::Tangent::Constant(0.1));
  std::vector<int> va(5);
  std::vector<int> vb(5);
  for (int k = 0; k < 5; ++k) {
    irrr->AddPose(a, k, k, k == 0 ? nullptr : &step, k == 0 ? nullptr : &information, &va[k]);
    irrr->AddPose(b, 10 + k, k, k == 0 ? nullptr : &step, k == 0 ? nullptr : &information, &vb[k]);
  }
  irrr->AddLoop(va[4], va[0], Pose(), information, nullptr);
  irrr->AddLoop(vb[3], va[1], Pose(), information, nullptr);
  irrr->Flush();
}

}  // namespace fuzz
}  // namespace irrr

#endif  // IRRR_TESTS_FUZZ_TWO_SESSIONS_H_
