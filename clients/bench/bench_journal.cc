// irrr-bench-journal: what the daemon's journal costs under each fsync policy.
//
//   irrr-bench-journal [--dir DIR] [--records N] [--batch B]
//
// Appends N records of a keyframe's size (an encoded keyframe_t) in batches of B (the worker
// appends each batch it takes before applying it), under "never", "batch" and "always", then
// reads the journal back as a restart does. Prints, per policy, microseconds per record, records
// per second, and the read-back rate. The figures depend on the file system under DIR (default:
// the current folder).

#include <sysexits.h>

#include <chrono>
#include <cstdio>
#include <string>
#include <vector>

#include <fmt/core.h>
#include <CLI/CLI.hpp>

#include "daemon/journal.h"
#include "daemon/wire.h"
#include "irrr/keyframe_t.hpp"

namespace irrr {
namespace {

int Run(const std::string& dir, int records, int batch) {
  keyframe_t k{};
  k.header = {0, 0, "robot0/frontend"};
  k.dim = keyframe_t::DIM_SE2;
  k.odom_pose.q[0] = k.odom_delta.q[0] = 1.0;
  const std::vector<uint8_t> bytes = EncodeMessage(k);
  fmt::print("journal   {} records of {} bytes (an encoded keyframe_t), batches of {}, in {}\n",
             records,
             bytes.size(),
             batch,
             dir);
  fmt::print(
      "{:<8} {:>14} {:>14} {:>16}\n", "fsync", "us / record", "records / s", "read back / s");
  for (const auto& [policy, name] : {std::make_pair(JournalSyncPolicy::kNever, "never"),
                                     std::make_pair(JournalSyncPolicy::kBatch, "batch"),
                                     std::make_pair(JournalSyncPolicy::kAlways, "always")}) {
    const std::string path = dir + "/irrr-bench-journal." + name;
    std::remove(path.c_str());
    double write_s = 0.0;
    {
      Journal journal;
      JournalRecovery recovery;
      if (Status s = journal.Open(path, policy, &recovery); !s.ok()) {
        fmt::print(stderr, "irrr-bench-journal: {}\n", s.message());
        return EX_CANTCREAT;
      }
      std::vector<JournalRecord> chunk(batch, JournalRecord{JournalRecord::kKeyframe, 0, bytes});
      const auto start = std::chrono::steady_clock::now();
      for (int written = 0; written < records; written += batch) {
        if (Status s = journal.Append(chunk); !s.ok()) {
          fmt::print(stderr, "irrr-bench-journal: {}\n", s.message());
          return EX_IOERR;
        }
      }
      write_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    }
    const auto start = std::chrono::steady_clock::now();
    Journal journal;
    JournalRecovery recovery;
    if (Status s = journal.Open(path, policy, &recovery); !s.ok()) {
      fmt::print(stderr, "irrr-bench-journal: {}\n", s.message());
      return EX_IOERR;
    }
    const double read_s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    const double n = static_cast<double>(recovery.records.size());
    fmt::print(
        "{:<8} {:>14.2f} {:>14.0f} {:>16.0f}\n", name, 1e6 * write_s / n, n / write_s, n / read_s);
    std::remove(path.c_str());
  }
  return EX_OK;
}

}  // namespace
}  // namespace irrr

int main(int argc, char** argv) {
  std::string dir = ".";
  int records = 20000;
  int batch = 10;
  CLI::App app{"irrr-bench-journal: the cost of the daemon's journal under each fsync policy"};
  app.add_option("--dir", dir, "where to write the journals")->capture_default_str();
  app.add_option("--records", records, "records per policy")
      ->check(CLI::Range(1, 100000000))
      ->capture_default_str();
  app.add_option("--batch", batch, "records per append (the worker's batch)")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  return irrr::Run(dir, records, batch);
}
