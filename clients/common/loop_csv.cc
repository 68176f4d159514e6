#include "clients/common/loop_csv.h"

#include <map>

#include <charconv>
#include <cmath>
#include <limits>
#include <string>
#include <system_error>

#include <fmt/format.h>

namespace irrr {

const char* const kDecisionsCsvHeader =
    "edge_index,from,to,session_from,session_to,cluster,accepted,state,step,chi2,threshold";
const char* const kLabelsCsvHeader = "edge_index,from,to,outlier,group";

namespace {

// 17 significant digits read back to the same double; NaN (not decided by a test) is empty.
std::string FormatStatistic(double value) {
  return std::isnan(value) ? std::string() : fmt::format("{:.17g}", value);
}

std::vector<std::string> SplitFields(const std::string& line) {
  std::vector<std::string> fields;
  size_t start = 0;
  while (true) {
    const size_t comma = line.find(',', start);
    fields.push_back(line.substr(start, comma - start));
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  return fields;
}

template <class Integer>
bool ParseInteger(const std::string& text, Integer* value) {
  const char* end = text.data() + text.size();
  const auto [ptr, ec] = std::from_chars(text.data(), end, *value);
  return ec == std::errc() && ptr == end && !text.empty();
}

// Empty means NaN (see FormatStatistic).
bool ParseStatistic(const std::string& text, double* value) {
  if (text.empty()) {
    *value = std::numeric_limits<double>::quiet_NaN();
    return true;
  }
  const char* end = text.data() + text.size();
  const auto [ptr, ec] = std::from_chars(text.data(), end, *value);
  return ec == std::errc() && ptr == end;
}

bool ParseState(const std::string& text, LoopState* state) {
  for (LoopState candidate : {LoopState::kPending,
                              LoopState::kAccepted,
                              LoopState::kRejectedLinkTest,
                              LoopState::kRejectedClusterTest,
                              LoopState::kRejectedJointTest,
                              LoopState::kReversed}) {
    if (text == LoopStateName(candidate)) {
      *state = candidate;
      return true;
    }
  }
  return false;
}

// Reads the header and hands every further non-empty line's fields (with its line number) to
// `parse_row`, which returns an error message or "".
template <class ParseRow>
Status ReadTable(std::istream& in, const char* header, size_t num_fields, ParseRow parse_row) {
  std::string line;
  int line_number = 0;
  auto strip = [](std::string* text) {
    if (!text->empty() && text->back() == '\r') text->pop_back();
  };
  if (!std::getline(in, line)) return Status::Error("empty file: expected the header line");
  ++line_number;
  strip(&line);
  if (line != header) {
    return Status::Error(
        fmt::format("line 1: expected the header \"{}\", got \"{}\"", header, line));
  }
  while (std::getline(in, line)) {
    ++line_number;
    strip(&line);
    if (line.empty()) continue;
    const std::vector<std::string> fields = SplitFields(line);
    if (fields.size() != num_fields) {
      return Status::Error(
          fmt::format("line {}: {} fields, expected {}", line_number, fields.size(), num_fields));
    }
    if (const std::string error = parse_row(fields); !error.empty()) {
      return Status::Error(fmt::format("line {}: {}", line_number, error));
    }
  }
  if (in.bad()) return Status::Error("read failed");
  return Status::Ok();
}

}  // namespace

Status WriteDecisionsCsv(std::ostream& out, const std::vector<DecisionRow>& rows) {
  out << kDecisionsCsvHeader << '\n';
  for (const DecisionRow& row : rows) {
    const LoopDecision& d = row.decision;
    out << fmt::format("{},{},{},{},{},{},{},{},{},{},{}\n",
                       row.edge_index,
                       row.from,
                       row.to,
                       row.session_from,
                       row.session_to,
                       d.cluster,
                       d.state == LoopState::kAccepted ? 1 : 0,
                       LoopStateName(d.state),
                       d.step,
                       FormatStatistic(d.chi2),
                       FormatStatistic(d.threshold));
  }
  if (!out) return Status::Error("write failed");
  return Status::Ok();
}

Status ReadDecisionsCsv(std::istream& in, std::vector<DecisionRow>* rows) {
  std::vector<DecisionRow> read;
  const Status status =
      ReadTable(in, kDecisionsCsvHeader, 11, [&read](const std::vector<std::string>& f) {
        DecisionRow row;
        int accepted = -1;
        if (!ParseInteger(f[0], &row.edge_index) || !ParseInteger(f[1], &row.from) ||
            !ParseInteger(f[2], &row.to) || !ParseInteger(f[3], &row.session_from) ||
            !ParseInteger(f[4], &row.session_to) || !ParseInteger(f[5], &row.decision.cluster) ||
            !ParseInteger(f[6], &accepted) || !ParseInteger(f[8], &row.decision.step)) {
          return std::string("expected integers in every column but state, chi2 and threshold");
        }
        if (!ParseState(f[7], &row.decision.state)) return "unknown state \"" + f[7] + "\"";
        if (accepted != (row.decision.state == LoopState::kAccepted ? 1 : 0)) {
          return "accepted " + f[6] + " disagrees with state " + f[7];
        }
        if (!ParseStatistic(f[9], &row.decision.chi2) ||
            !ParseStatistic(f[10], &row.decision.threshold)) {
          return std::string("chi2 and threshold must be numbers or empty");
        }
        read.push_back(row);
        return std::string();
      });
  if (!status.ok()) return status;
  rows->swap(read);
  return Status::Ok();
}

template <class Pose>
std::vector<DecisionRow> DecisionRowsInFileOrder(const GraphFile<Pose>& file,
                                                 const PoseGraph<Pose>& graph,
                                                 const std::vector<int>& graph_edge_of_file_edge,
                                                 const std::vector<LoopDecision>& decisions) {
  IRRR_CHECK(graph_edge_of_file_edge.size() == file.edges.size());
  IRRR_CHECK(static_cast<int>(decisions.size()) == graph.num_edges());
  std::vector<DecisionRow> rows;
  for (size_t k = 0; k < file.edges.size(); ++k) {
    const int e = graph_edge_of_file_edge[k];
    const Edge<Pose>& edge = graph.edge(e);
    if (edge.kind != EdgeKind::kLoop) continue;
    DecisionRow row;
    row.edge_index = static_cast<int>(k);
    row.from = graph.vertex(edge.from).id;
    row.to = graph.vertex(edge.to).id;
    row.session_from = graph.session(graph.vertex(edge.from).session).id;
    row.session_to = graph.session(graph.vertex(edge.to).session).id;
    row.decision = decisions[e];
    rows.push_back(row);
  }
  return rows;
}

Status WriteLabelsCsv(std::ostream& out, const std::vector<LabelRow>& rows) {
  out << kLabelsCsvHeader << '\n';
  for (const LabelRow& row : rows) {
    out << fmt::format(
        "{},{},{},{},{}\n", row.edge_index, row.from, row.to, row.outlier ? 1 : 0, row.group);
  }
  if (!out) return Status::Error("write failed");
  return Status::Ok();
}

Status ReadLabelsCsv(std::istream& in, std::vector<LabelRow>* rows) {
  std::vector<LabelRow> read;
  const Status status =
      ReadTable(in, kLabelsCsvHeader, 5, [&read](const std::vector<std::string>& f) {
        LabelRow row;
        int outlier = -1;
        if (!ParseInteger(f[0], &row.edge_index) || !ParseInteger(f[1], &row.from) ||
            !ParseInteger(f[2], &row.to) || !ParseInteger(f[3], &outlier) ||
            !ParseInteger(f[4], &row.group)) {
          return std::string("expected integers in every column");
        }
        if (outlier != 0 && outlier != 1) return "outlier must be 0 or 1, got " + f[3];
        row.outlier = outlier == 1;
        read.push_back(row);
        return std::string();
      });
  if (!status.ok()) return status;
  rows->swap(read);
  return Status::Ok();
}

template std::vector<DecisionRow> DecisionRowsInFileOrder<Pose2>(const GraphFile<Pose2>&,
                                                                 const PoseGraph<Pose2>&,
                                                                 const std::vector<int>&,
                                                                 const std::vector<LoopDecision>&);
template std::vector<DecisionRow> DecisionRowsInFileOrder<Pose3>(const GraphFile<Pose3>&,
                                                                 const PoseGraph<Pose3>&,
                                                                 const std::vector<int>&,
                                                                 const std::vector<LoopDecision>&);

double Scores::precision() const {
  const int accepted = accepted_true + accepted_wrong;
  return accepted > 0 ? static_cast<double>(accepted_true) / accepted : 1.0;
}

double Scores::recall() const {
  return true_loops > 0 ? static_cast<double>(accepted_true) / true_loops : 1.0;
}

Status ScoreDecisions(const std::vector<LabelRow>& labels,
                      const std::vector<DecisionRow>& decisions,
                      Scores* scores) {
  std::map<int, const DecisionRow*> by_edge;
  for (const DecisionRow& row : decisions) by_edge[row.edge_index] = &row;
  Scores out;
  for (const LabelRow& label : labels) {
    const auto it = by_edge.find(label.edge_index);
    if (it == by_edge.end()) {
      return Status::Error("edge_index " + std::to_string(label.edge_index) +
                           " has no decision (is it a loop hypothesis of the input?)");
    }
    const bool accepted = it->second->decision.state == LoopState::kAccepted;
    (label.outlier ? out.wrong_loops : out.true_loops) += 1;
    (label.outlier ? out.accepted_wrong : out.accepted_true) += accepted ? 1 : 0;
  }
  *scores = out;
  return Status::Ok();
}

std::string FormatScores(const Scores& s) {
  return fmt::format(
      "precision {:.4f} ({} of {} accepted are true), recall {:.4f} ({} of {} true loops), {} of "
      "{} wrong loops accepted",
      s.precision(),
      s.accepted_true,
      s.accepted_true + s.accepted_wrong,
      s.recall(),
      s.accepted_true,
      s.true_loops,
      s.accepted_wrong,
      s.wrong_loops);
}

}  // namespace irrr
