#include "clients/bench/accuracy_cases.h"

#include <fmt/core.h>

namespace irrr {

std::vector<Case> AllCases() {
  struct Clean {
    std::string name;
    std::string graph;
    ReferenceKind reference;
    std::string reference_path;
  };
  const std::vector<Clean> clean = {
      {"manhattan",
       "datasets/manhattan/vertigo/Olson/manhattanOlson3500.g2o",
       ReferenceKind::kPoseLines,
       "datasets/manhattan/vertigo/groundTruth/manhattanOlson3500_nodes_groundTruth.dat"},
      {"intel", "datasets/intel/vertigo/intel.g2o", ReferenceKind::kOracle, ""},
      {"city10000",
       "datasets/city10000/vertigo/city10000.g2o",
       ReferenceKind::kIsamEdges,
       "datasets/city10000/isam/groundtruth/city10000_groundtruth.txt"},
      {"sphere2500",
       "datasets/sphere2500/vertigo/sphere2500.g2o",
       ReferenceKind::kIsamEdges,
       "datasets/sphere2500/isam/groundtruth/sphere2500_groundtruth.txt"},
  };
  const OutlierMode modes[] = {OutlierMode::kRandom,
                               OutlierMode::kLocal,
                               OutlierMode::kRandomGrouped,
                               OutlierMode::kLocalGrouped};
  std::vector<Case> cases;
  for (const Clean& c : clean) {
    for (int count : {100, 1000}) {
      for (OutlierMode mode : modes) {
        Case k;
        k.name = fmt::format("{}-{}-{}", c.name, OutlierModeName(mode), count);
        k.kind = CaseKind::kSynthetic;
        k.graph = c.graph;
        k.reference = c.reference;
        k.reference_path = c.reference_path;
        k.mode = mode;
        k.outliers = count;
        cases.push_back(k);
      }
    }
  }
  // The failure families a real place recognizer and odometry make (perceptual aliasing, odometry
  // noisier than its information, odometry faults), on the clean datasets above and on M3500b
  // (Manhattan with much noisier headings), the parking garage and Torus3D.
  std::vector<Clean> families = clean;
  families.insert(
      families.begin() + 1,
      {"m3500b", "datasets/manhattan/carlone/input_M3500b_g2o.g2o", ReferenceKind::kOracle, ""});
  families.push_back({"garage", "datasets/garage/parking-garage.g2o", ReferenceKind::kOracle, ""});
  families.push_back({"torus3d", "datasets/torus3d/torus3D.g2o", ReferenceKind::kOracle, ""});
  struct Family {
    std::string name;
    OutlierMode mode;
    int outliers;
    double odometry_noise;
    int odometry_faults;
  };
  const std::vector<Family> family_rows = {
      {"aliased-300", OutlierMode::kAliased, 300, 0.0, 0},
      {"aliased-1000", OutlierMode::kAliased, 1000, 0.0, 0},
      {"aliased-grouped-300", OutlierMode::kAliasedGrouped, 300, 0.0, 0},
      {"aliased-grouped-1000", OutlierMode::kAliasedGrouped, 1000, 0.0, 0},
      {"noisy2-random-grouped-1000", OutlierMode::kRandomGrouped, 1000, 2.0, 0},
      {"noisy3-random-grouped-1000", OutlierMode::kRandomGrouped, 1000, 3.0, 0},
      {"faults5-random-100", OutlierMode::kRandom, 100, 0.0, 5},
  };
  for (const Clean& c : families) {
    for (const Family& f : family_rows) {
      Case k;
      k.name = fmt::format("{}-{}", c.name, f.name);
      k.kind = CaseKind::kSynthetic;
      k.graph = c.graph;
      k.reference = c.reference;
      k.reference_path = c.reference_path;
      k.mode = f.mode;
      k.outliers = f.outliers;
      k.odometry_noise = f.odometry_noise;
      k.odometry_faults = f.odometry_faults;
      cases.push_back(k);
    }
  }
  const char* alphas[] = {"0.00", "0.25", "0.50", "0.75", "1.00"};
  // KITTI 00 and 05; and from 00 a real sequence whose hypotheses are all wrong (its labelled
  // true loops removed).
  std::vector<Case> wrong_only;
  for (const char* sequence : {"00", "05"}) {
    for (const char* alpha : alphas) {
      const std::string folder = fmt::format("datasets/kitti_rrr/{}/kitti_{}", sequence, sequence);
      Case k;
      k.name = fmt::format("kitti{}-alpha-{}", sequence, alpha);
      k.kind = CaseKind::kLabelled;
      k.graph = fmt::format("{}_alpha_{}.g2o", folder, alpha);
      k.labels = fmt::format("{}_alpha_{}_GT_LC.txt", folder, alpha);
      k.reference = ReferenceKind::kGraphFile;
      k.reference_path = folder + "_GT.g2o";
      cases.push_back(k);
      if (std::string(sequence) == "00") {
        k.name = fmt::format("kitti00-wrong-only-alpha-{}", alpha);
        k.wrong_only = true;
        wrong_only.push_back(k);
      }
    }
  }
  cases.insert(cases.end(), wrong_only.begin(), wrong_only.end());
  for (const char* alpha : {"0.000", "0.250", "0.500", "0.750", "1.000"}) {
    Case k;
    k.name = fmt::format("bicocca25b-alpha-{}", alpha);
    k.kind = CaseKind::kUnlabelled;
    k.graph = fmt::format("datasets/rrr_bicocca25b/B25b_{}.g2o", alpha);
    k.reference = ReferenceKind::kTimestampGps;
    k.reference_path = "datasets/rrr_bicocca25b/timestamps/Bicocca_2009-02-25b-GT-extended.csv";
    k.timestamps = "datasets/rrr_bicocca25b/timestamps/B25b_timestamps.txt";
    cases.push_back(k);
  }
  // Bovisa (RAWSEEDS, the RRR author's bag-of-words loops): never tuned on. Its GPS files hold
  // one fix per 10 odometry poses: their step lengths match the odometry's 10-pose steps (1718 m
  // against 1714 m over Bovisa 04, 1893 against 1882 over 06).
  for (const char* session : {"04", "06"}) {
    Case k;
    k.name = fmt::format("bovisa{}", session);
    k.kind = CaseKind::kUnlabelled;
    k.graph = fmt::format("datasets/rrr_bovisa/Bovisa{}_odometry_bow_tr.g2o", session);
    k.reference = ReferenceKind::kStridedGps;
    k.reference_path = fmt::format("datasets/rrr_bovisa/Bovisa{}_GT_GPS.g2o", session);
    cases.push_back(k);
  }
  return cases;
}

}  // namespace irrr
