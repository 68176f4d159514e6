#include "clients/bench/accuracy_report.h"

#include <sched.h>
#include <unistd.h>

#include <algorithm>
#include <ctime>
#include <fstream>
#include <ostream>
#include <utility>

#include <fmt/core.h>

#include "clients/bench/reference_files.h"
#include "clients/common/graph_files.h"
#include "core/irrr_options.h"

namespace irrr {
namespace {

// One line per case and method configuration over the seeds of a sweep.
std::string SweepSummary(const std::vector<Row>& rows) {
  std::vector<std::pair<std::string, std::string>> keys;
  for (const Row& r : rows) {
    const auto key = std::make_pair(r.case_name, r.method + " (" + r.configuration + ")");
    if (std::find(keys.begin(), keys.end(), key) == keys.end()) keys.push_back(key);
  }
  std::string out = "Sweep: per case and method, over its seeds:\n\n";
  for (const auto& [case_name, method] : keys) {
    std::vector<double> recalls;
    int stopped = 0;
    int none_wrong = 0;
    int near_lowest = 0;
    int compared = 0;  // --order both
    int same_order = 0;
    const Row* worst = nullptr;
    for (const Row& r : rows) {
      if (r.case_name != case_name || r.method + " (" + r.configuration + ")" != method) continue;
      if (r.stopped) {
        ++stopped;
        continue;
      }
      recalls.push_back(r.recall);
      none_wrong += r.accepted_wrong == 0 ? 1 : 0;
      near_lowest += r.chi2_ratio <= 1.01 ? 1 : 0;
      compared += r.order_diffs >= 0 ? 1 : 0;
      same_order += r.order_diffs == 0 ? 1 : 0;
      if (worst == nullptr || r.accepted_wrong > worst->accepted_wrong ||
          (r.accepted_wrong == worst->accepted_wrong && r.recall < worst->recall)) {
        worst = &r;
      }
    }
    std::sort(recalls.begin(), recalls.end());
    if (recalls.empty()) {
      out += fmt::format("* {} {}: every run stopped\n", case_name, method);
      continue;
    }
    out += fmt::format(
        "* {} {}: {} runs, {} with no wrong loop, worst seed {} ({} wrong, recall {:.3f}), "
        "median recall {:.3f}, chi2 within 1% of the lowest in {}{}{}\n",
        case_name,
        method,
        recalls.size(),
        none_wrong,
        worst->seed,
        worst->accepted_wrong,
        worst->recall,
        recalls[(recalls.size() - 1) / 2],
        near_lowest,
        compared > 0 ? fmt::format(", {} of {} with 0 order diffs", same_order, compared)
                     : std::string(),
        stopped > 0 ? fmt::format(", {} stopped", stopped) : std::string());
  }
  return out;
}

const char* kTableHeader =
    "| case | failures | method | graph dof | variant | poses | loops true/false | accepted | "
    "acc. true | acc. false | precision | recall | faults found | chi2 clean | lowest chi2 | "
    "chi2/lowest | ATE m | oracle ATE m | ATE/oracle | reference | time s | cpu s | peak MB | "
    "steps | step p50 ms | p90 ms | p99 ms | max ms |\n"
    "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    "---|---|---|---|---|\n";

std::string CpuModel() {
  std::ifstream in("/proc/cpuinfo");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("model name", 0) == 0) {
      const size_t colon = line.find(':');
      if (colon != std::string::npos) {
        size_t start = line.find_first_not_of(' ', colon + 1);
        return start == std::string::npos ? "" : line.substr(start);
      }
    }
  }
  return "unknown";
}

// What nproc prints: the CPUs this process may run on.
int UsableCpus() {
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof(set), &set) == 0) return CPU_COUNT(&set);
  return static_cast<int>(sysconf(_SC_NPROCESSORS_ONLN));
}

}  // namespace

// The table's header; --order both adds the order diffs column at its end.
std::string TableHeader(RunOrder order) {
  const std::string header = kTableHeader;
  if (order != RunOrder::kBoth) return header;
  const size_t end = header.find('\n');
  return header.substr(0, end) + " order diffs |\n" +
         header.substr(end + 1, header.size() - end - 2) + "---|\n";
}

std::string SummaryLines(const std::vector<Row>& rows, bool sweep) {
  std::string out;
  if (sweep) out += SweepSummary(rows);
  for (const Row& r : rows) {
    if (!sweep && r.order_diffs >= 0) {
      out += fmt::format("Order: {} {} ({}) accepted {} loop(s) in one order and not the other\n",
                         r.case_name,
                         r.method,
                         r.configuration,
                         r.order_diffs);
    }
    if (r.case_name == "manhattan-random-1000" && r.method == "irrr") {
      out += fmt::format(
          "iRRR incremental over Manhattan + 1000 random outliers ({}): {:.2f} s ({:.2f} s "
          "CPU)\n",
          r.configuration,
          r.seconds,
          r.cpu_seconds);
    }
  }
  return out;
}

std::string MachineDescription() {
  return fmt::format("{} CPU(s) (nproc), {}", UsableCpus(), CpuModel());
}

std::string UtcNow() {
  const std::time_t now = std::time(nullptr);
  std::tm utc{};
  gmtime_r(&now, &utc);
  char text[64];
  std::strftime(text, sizeof(text), "%Y-%m-%d %H:%M UTC", &utc);
  return text;
}

// A command line as a shell would accept it back (arguments with odd characters single-quoted).
std::string QuotedCommand(int argc, char** argv) {
  std::string out;
  for (int k = 0; k < argc; ++k) {
    std::string arg = argv[k];
    const bool plain = !arg.empty() && arg.find_first_not_of(
                                           "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"
                                           "0123456789-_./=,:+@%") == std::string::npos;
    if (!plain) {
      std::string quoted = "'";
      for (char ch : arg) quoted += ch == '\'' ? std::string("'\\''") : std::string(1, ch);
      arg = quoted + "'";
    }
    out += (k == 0 ? "" : " ") + arg;
  }
  return out;
}

Status WriteReport(const std::string& path,
                   const ReportContext& context,
                   const std::vector<Row>& rows,
                   const std::vector<std::string>& failures) {
  return WriteFileAtomically(path, [&](std::ostream& out) {
    out << "# iRRR accuracy benchmark\n\n";
    out << "Regenerated by `" << context.command << "` on " << context.machine << ", "
        << context.date << ".\n";
    if (static_cast<int>(rows.size()) < context.planned_rows || !failures.empty()) {
      out << "\n**Partial:** " << rows.size() << " of " << context.planned_rows << " rows";
      out << (failures.empty() ? "." : ", failed cases below.") << "\n";
    }
    out << "\nSynthetic outliers: core/outliers.h MakeOutliers appended to the clean graph, seed "
        << context.outliers.seed << ", grouped modes in groups of " << context.outliers.group_size
        << ", local window " << context.outliers.local_window
        << " poses; every original loop is true. iRRR options: alpha " << IrrrOptions().alpha
        << ", cluster gap " << IrrrOptions().cluster_gap
        << " poses; variant \"paper\" = the paper's Algorithms 1-2 as written, \"default\" = "
           "the strengthened tests (algorithm-notes, \"Beyond the paper\").\n\n";
    out << "Columns: precision = accepted true / accepted; recall = accepted true / true "
           "loops; ATE = translation RMSE after rigid alignment of each connected component "
           "(odometry + accepted loops) to the reference; oracle = odometry + exactly the true "
           "loops, optimized from dead reckoning; time = wall time of the whole run (iRRR: input "
           "fed in arrival order and every step; RRR: batch), cpu = this process's CPU time over "
           "the same span (lower than time when the machine is shared); steps = iRRR steps "
           "(closed clusters) and their "
           "optimizations; step latency = wall time of each RunStep. Reference \"GT (iSAM "
           "chain)\": the noise-free sequential edges of the iSAM ground-truth file chained from "
           "the origin; \"oracle\": no ground truth exists, the oracle is the reference; \"GPS "
           "n/N\": Bicocca vertices with a GPS fix within "
        << kGpsMatchSeconds
        << " s (vertex k has time line k of B25b_timestamps.txt), Bovisa vertices 0, " << kGpsStride
        << ", " << 2 * kGpsStride
        << ", ... (fix k of the GT_GPS file); Bicocca and Bovisa ship no loop labels, so their "
           "precision, recall and oracle are \"-\".\n\n";
    out << RunOrderNote(context.order);
    out << TableHeader(context.order);
    for (const Row& r : rows) out << r.markdown << "\n";
    const std::string summary = SummaryLines(rows, context.sweep);
    if (!summary.empty()) out << "\n" << summary;
    if (!failures.empty()) {
      out << "\nFailed cases:\n\n";
      for (const std::string& f : failures) out << "* " << f << "\n";
    }
    return Status::Ok();
  });
}

}  // namespace irrr
