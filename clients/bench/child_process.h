#ifndef IRRR_CLIENTS_BENCH_CHILD_PROCESS_H_
#define IRRR_CLIENTS_BENCH_CHILD_PROCESS_H_

// A piece of work run in a child process, so that its peak memory is its own and a run that takes
// too long can be stopped: the child computes a vector of numbers and sends it back through a
// pipe.

#include <functional>
#include <vector>

#include "core/status.h"

namespace irrr {

struct ChildResult {
  std::vector<double> numbers;  // what the work returned
  long peak_rss_kb = 0;         // the child's maximum resident set size
  bool stopped = false;         // still running after the limit: killed, no numbers
};

// Runs `work` in a forked child and waits for its numbers. With `limit_seconds` > 0, a child still
// running after that long is killed and the result marked stopped. Fails when the child fails (it
// returns false from `work`, dies, or its numbers do not arrive whole) or a system call does.
Status RunInChildProcess(const std::function<bool(std::vector<double>*)>& work,
                         double limit_seconds,
                         ChildResult* result);

}  // namespace irrr

#endif  // IRRR_CLIENTS_BENCH_CHILD_PROCESS_H_
