#include "core/sparse_cholesky.h"

#include <dlfcn.h>

#include <mutex>
#include <random>
#include <thread>

#include <Eigen/Dense>
#include <catch2/catch.hpp>

namespace irrr {
namespace {

// Upper-triangle compressed columns of a dense symmetric matrix, keeping explicit zeros where
// `pattern` says so.
void ToUpperColumns(const Eigen::MatrixXd& dense,
                    const Eigen::MatrixXi& pattern,
                    std::vector<int>* starts,
                    std::vector<int>* rows,
                    std::vector<double>* values) {
  const int n = static_cast<int>(dense.rows());
  starts->assign(1, 0);
  for (int c = 0; c < n; ++c) {
    for (int r = 0; r <= c; ++r) {
      if (pattern(r, c) == 0) continue;
      rows->push_back(r);
      values->push_back(dense(r, c));
    }
    starts->push_back(static_cast<int>(rows->size()));
  }
}

// A random sparse SPD matrix: a banded matrix plus a few long-range couplings, made diagonally
// dominant.
Eigen::MatrixXd RandomSparseSpd(int n, uint32_t seed, Eigen::MatrixXi* pattern) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> value(-1.0, 1.0);
  std::uniform_int_distribution<int> index(0, n - 1);
  Eigen::MatrixXd a = Eigen::MatrixXd::Zero(n, n);
  *pattern = Eigen::MatrixXi::Identity(n, n);
  auto couple = [&](int i, int j) {
    const double v = value(rng);
    a(i, j) = a(j, i) = v;
    (*pattern)(i, j) = (*pattern)(j, i) = 1;
  };
  for (int i = 0; i + 1 < n; ++i) couple(i, i + 1);
  for (int k = 0; k < n / 4; ++k) {
    const int i = index(rng);
    const int j = index(rng);
    if (i != j) couple(i, j);
  }
  for (int i = 0; i < n; ++i) a(i, i) = a.row(i).cwiseAbs().sum() + 1.0;
  return a;
}

// A random sparse SPD system, dense and as the upper-triangle compressed columns SparseCholesky
// takes.
struct SpdSystem {
  Eigen::MatrixXd dense;
  std::vector<int> starts;
  std::vector<int> rows;
  std::vector<double> values;
};

SpdSystem RandomSystem(int n, uint32_t seed) {
  SpdSystem system;
  Eigen::MatrixXi pattern;
  system.dense = RandomSparseSpd(n, seed, &pattern);
  ToUpperColumns(system.dense, pattern, &system.starts, &system.rows, &system.values);
  return system;
}

TEST_CASE("CHOLMOD solves a sparse SPD system like a dense Cholesky", "[sparse_cholesky]") {
  const uint32_t seed = GENERATE(1u, 2u, 3u);
  INFO("seed " << seed);
  constexpr int kSize = 60;
  const SpdSystem spd = RandomSystem(kSize, seed);

  SparseCholesky cholesky;
  cholesky.SetPattern(kSize, spd.starts, spd.rows);
  REQUIRE(cholesky.size() == kSize);
  REQUIRE(cholesky.num_nonzeros() == static_cast<int>(spd.values.size()));
  std::copy(spd.values.begin(), spd.values.end(), cholesky.mutable_values());
  std::string message;
  REQUIRE(cholesky.Factorize(&message) == LinearSolverStatus::kSuccess);

  const Eigen::VectorXd b = Eigen::VectorXd::LinSpaced(kSize, -1.0, 2.0);
  Eigen::VectorXd x;
  REQUIRE(cholesky.Solve(b, &x));
  const Eigen::VectorXd expected = spd.dense.llt().solve(b);
  // Both solvers are backward stable on this well-conditioned matrix.
  CHECK((x - expected).lpNorm<Eigen::Infinity>() < 1e-12);
  CHECK(cholesky.factor_nonzeros() >= kSize);
}

TEST_CASE("New values with the same pattern reuse the symbolic analysis", "[sparse_cholesky]") {
  constexpr int kSize = 40;
  const SpdSystem spd = RandomSystem(kSize, 7);
  SparseCholesky cholesky;
  cholesky.SetPattern(kSize, spd.starts, spd.rows);
  for (int round = 1; round <= 3; ++round) {
    // Scaling keeps the pattern and changes the solution by the inverse factor.
    for (size_t k = 0; k < spd.values.size(); ++k) {
      cholesky.mutable_values()[k] = round * spd.values[k];
    }
    REQUIRE(cholesky.Factorize(nullptr) == LinearSolverStatus::kSuccess);
    Eigen::VectorXd x;
    REQUIRE(cholesky.Solve(Eigen::VectorXd::Ones(kSize), &x));
    CHECK((spd.dense * x * round - Eigen::VectorXd::Ones(kSize)).norm() < 1e-12);
  }
  CHECK(cholesky.num_analyses() == 1);
  CHECK(cholesky.num_factorizations() == 3);
}

TEST_CASE("Permuting once per pattern gives CHOLMOD's factor bit for bit", "[sparse_cholesky]") {
  // The matrix permuted by SparseCholesky must be the one CHOLMOD builds at each factorization:
  // same fill, same solutions to the last bit, over refactorizations with new values.
  const uint32_t seed = GENERATE(1u, 2u, 3u, 4u);
  INFO("seed " << seed);
  constexpr int kSize = 300;
  const SpdSystem spd = RandomSystem(kSize, seed);
  SparseCholesky once(/*permute_once=*/true);
  SparseCholesky each_time(/*permute_once=*/false);
  once.SetPattern(kSize, spd.starts, spd.rows);
  each_time.SetPattern(kSize, spd.starts, spd.rows);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> scale(0.5, 1.0);
  for (int round = 0; round < 3; ++round) {
    // Off-diagonal entries shrink by a random factor (the diagonal, last in each column, stays):
    // new values, still diagonally dominant.
    for (int c = 0; c < kSize; ++c) {
      for (int k = spd.starts[c]; k < spd.starts[c + 1]; ++k) {
        const bool diagonal = k == spd.starts[c + 1] - 1;
        const double v = diagonal ? spd.values[k] : spd.values[k] * scale(rng);
        once.mutable_values()[k] = v;
        each_time.mutable_values()[k] = v;
      }
    }
    REQUIRE(once.Factorize(nullptr) == LinearSolverStatus::kSuccess);
    REQUIRE(each_time.Factorize(nullptr) == LinearSolverStatus::kSuccess);
    REQUIRE(once.permuted_once());  // a matrix this sparse factorizes simplicially
    REQUIRE_FALSE(each_time.permuted_once());
    CHECK(once.factor_nonzeros() == each_time.factor_nonzeros());
    const Eigen::VectorXd b = Eigen::VectorXd::LinSpaced(kSize, -3.0, 1.0 + round);
    Eigen::VectorXd x_once;
    Eigen::VectorXd x_each_time;
    REQUIRE(once.Solve(b, &x_once));
    REQUIRE(each_time.Solve(b, &x_each_time));
    int differ = 0;
    for (int k = 0; k < kSize; ++k) differ += x_once[k] != x_each_time[k] ? 1 : 0;
    CHECK(differ == 0);
    CHECK(x_once.allFinite());
  }
}

TEST_CASE("An indefinite matrix is reported as not positive definite", "[sparse_cholesky]") {
  // [[1, 2], [2, 1]] has eigenvalues 3 and -1.
  SparseCholesky cholesky;
  cholesky.SetPattern(2, {0, 1, 3}, {0, 0, 1});
  double* v = cholesky.mutable_values();
  v[0] = 1.0;
  v[1] = 2.0;
  v[2] = 1.0;
  std::string message;
  CHECK(cholesky.Factorize(&message) == LinearSolverStatus::kNotPositiveDefinite);
  CHECK_THAT(message, Catch::Contains("not positive definite"));
  Eigen::VectorXd x;
  CHECK_FALSE(cholesky.Solve(Eigen::VectorXd::Ones(2), &x));
}

// What libcholmod's call to GOMP_parallel finds: the dynamic linker's first definition, which is
// the program's (core/serial_openmp.cc) when the program exports it. libgomp's would start a team
// of the four threads asked for.
TEST_CASE("CHOLMOD's OpenMP regions run once, in the thread that opens them", "[sparse_cholesky]") {
  using RegionEntry = void (*)(void (*)(void*), void*, unsigned, unsigned);
  const auto entry = reinterpret_cast<RegionEntry>(dlsym(RTLD_DEFAULT, "GOMP_parallel"));
  REQUIRE(entry != nullptr);
  struct Seen {
    std::mutex mutex;
    std::vector<std::thread::id> threads;
  } seen;
  entry(
      [](void* data) {
        auto* s = static_cast<Seen*>(data);
        std::lock_guard<std::mutex> lock(s->mutex);
        s->threads.push_back(std::this_thread::get_id());
      },
      &seen,
      4,
      0);
  REQUIRE(seen.threads.size() == 1);
  CHECK(seen.threads.front() == std::this_thread::get_id());
}

// What libcholmod's timer reads find (core/cholmod_timers.cc): the program's definition, which
// does not read the clock. libsuitesparseconfig's returns the wall-clock time in seconds.
TEST_CASE("CHOLMOD's timers do not read the clock", "[sparse_cholesky]") {
  using Timer = double (*)();
  const auto timer = reinterpret_cast<Timer>(dlsym(RTLD_DEFAULT, "SuiteSparse_time"));
  REQUIRE(timer != nullptr);
  CHECK(timer() == 0.0);
}

}  // namespace
}  // namespace irrr
