#ifndef IRRR_CLIENTS_BENCH_ACCURACY_REPORT_H_
#define IRRR_CLIENTS_BENCH_ACCURACY_REPORT_H_

// The accuracy benchmark's output: the table's rows, the summary lines after them, and the
// complete Markdown document --output writes.

#include <cstdint>
#include <string>
#include <vector>

#include "clients/bench/order_runs.h"
#include "core/outliers.h"
#include "core/status.h"

namespace irrr {

// One finished row of the table, and what the closing summary lines need.
struct Row {
  std::string markdown;
  std::string case_name;
  std::string method;
  std::string configuration;  // graph dof and variant
  uint32_t seed = 0;
  double seconds = 0.0;
  double cpu_seconds = 0.0;
  bool labelled = false;
  int accepted_wrong = 0;
  double recall = 0.0;
  double chi2_ratio = 0.0;  // chi2 over the clean edges / the lowest of the run's methods
  bool stopped = false;     // the method ran past --method-seconds
  int order_diffs = -1;     // --order both, iRRR: loops accepted in one order only (-1: none)
};

// The table's header; --order both adds the order diffs column at its end.
std::string TableHeader(RunOrder order);

// The lines after the table: with a sweep (`sweep`), one per case and method over its seeds;
// otherwise each run's order diffs, and the Manhattan + 1000 random time.
std::string SummaryLines(const std::vector<Row>& rows, bool sweep);

// What the document says of the run that made it.
struct ReportContext {
  std::string command;  // QuotedCommand
  std::string machine;  // MachineDescription
  std::string date;     // UtcNow
  OutlierOptions outliers;
  RunOrder order = RunOrder::kForward;
  bool sweep = false;
  int planned_rows = 0;
};

// A command line as a shell would accept it back (arguments with odd characters single-quoted).
std::string QuotedCommand(int argc, char** argv);
// "N CPU(s) (nproc), <CPU model>".
std::string MachineDescription();
std::string UtcNow();

// Writes the document (atomically) to `path`: the run's context, the table so far, the summary
// lines and the cases that failed.
Status WriteReport(const std::string& path,
                   const ReportContext& context,
                   const std::vector<Row>& rows,
                   const std::vector<std::string>& failures);

}  // namespace irrr

#endif  // IRRR_CLIENTS_BENCH_ACCURACY_REPORT_H_
