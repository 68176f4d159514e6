#ifndef IRRR_CLIENTS_COMMON_LOOP_CSV_H_
#define IRRR_CLIENTS_COMMON_LOOP_CSV_H_

// CSV tables about loop hypotheses, one row per hypothesis, for people and scoring scripts:
//  - decisions (irrr-batch --decisions, the daemon's listener):
//      edge_index,from,to,session_from,session_to,cluster,accepted,state,step,chi2,threshold
//  - labels (irrr-corrupt --labels): which hypotheses are injected outliers:
//      edge_index,from,to,outlier,group
// `edge_index` is the hypothesis' index in its file's edge list (odometry included), `from` and
// `to` are vertex ids. Rows are written in the order given; writers produce what the readers
// accept.

#include <cstdint>
#include <istream>
#include <ostream>
#include <vector>

#include "core/graph_io.h"
#include "core/irrr.h"
#include "core/pose_graph.h"
#include "core/status.h"

namespace irrr {

struct DecisionRow {
  int edge_index = -1;
  int64_t from = 0;  // vertex ids
  int64_t to = 0;
  int64_t session_from = 0;  // session ids
  int64_t session_to = 0;
  LoopDecision decision;
};

// The header line, without its newline.
extern const char* const kDecisionsCsvHeader;

// Writes the header and one line per row: `accepted` is 1 for LoopState::kAccepted and 0
// otherwise, `state` is LoopStateName, chi2 and threshold have 17 significant digits (they read
// back to the same double) and are empty when NaN. Fails if the stream fails.
Status WriteDecisionsCsv(std::ostream& out, const std::vector<DecisionRow>& rows);

// Reads what WriteDecisionsCsv writes (rows replace `rows`; untouched on error). Fails, naming
// the line, on a wrong header, a wrong number of fields, a field that is not a number, an
// unknown state name, or `accepted` disagreeing with `state`.
Status ReadDecisionsCsv(std::istream& in, std::vector<DecisionRow>* rows);

// The rows of every loop hypothesis of a file, in file order: `graph` was built from `file`
// (BuildPoseGraph, which gave `graph_edge_of_file_edge`) and `decisions` is indexed like the
// graph's edges (RunBatchRrr, RunIncrementalIrrr). Odometry edges get no row.
template <class Pose>
std::vector<DecisionRow> DecisionRowsInFileOrder(const GraphFile<Pose>& file,
                                                 const PoseGraph<Pose>& graph,
                                                 const std::vector<int>& graph_edge_of_file_edge,
                                                 const std::vector<LoopDecision>& decisions);

struct LabelRow {
  int edge_index = -1;
  int64_t from = 0;  // vertex ids
  int64_t to = 0;
  bool outlier = false;
  int group = -1;  // outliers: the injected group (0, 1, ...); true hypotheses: -1
};

extern const char* const kLabelsCsvHeader;

// Writes the header and one line per row (`outlier` as 1/0). Fails if the stream fails.
Status WriteLabelsCsv(std::ostream& out, const std::vector<LabelRow>& rows);

// Reads what WriteLabelsCsv writes (rows replace `rows`; untouched on error). Fails, naming the
// line, on a wrong header, a wrong number of fields or a field that is not an integer.
Status ReadLabelsCsv(std::istream& in, std::vector<LabelRow>* rows);

// Decisions scored against labels, rows matched by edge_index.
struct Scores {
  int true_loops = 0;
  int wrong_loops = 0;
  int accepted_true = 0;
  int accepted_wrong = 0;
  double precision() const;  // 1 when nothing was accepted
  double recall() const;     // 1 when there is no true loop
};

// Fails on a label whose edge_index has no decision row.
Status ScoreDecisions(const std::vector<LabelRow>& labels,
                      const std::vector<DecisionRow>& decisions,
                      Scores* scores);

// "precision 1.0000 (892 of 892 accepted are true), recall 0.9966 (892 of 895 true loops), 0 of
// 60 wrong loops accepted"
std::string FormatScores(const Scores& scores);

}  // namespace irrr

#endif  // IRRR_CLIENTS_COMMON_LOOP_CSV_H_
