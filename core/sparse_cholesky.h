#ifndef IRRR_CORE_SPARSE_CHOLESKY_H_
#define IRRR_CORE_SPARSE_CHOLESKY_H_

// Sparse Cholesky factorization of a symmetric positive-definite matrix with CHOLMOD
// (simplicial or supernodal as CHOLMOD judges best, AMD fill-reducing ordering). CHOLMOD stays
// behind a pImpl: cholmod.h is included by sparse_cholesky.cc only, and CHOLMOD's own printing is
// silenced.
//
// The pattern (upper triangle, compressed columns) is set once; the symbolic analysis is done on
// the first factorization after SetPattern and reused by every later one, so a caller that solves
// many systems of one shape pays for the ordering once.

#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace irrr {

enum class LinearSolverStatus {
  kSuccess,
  kNotPositiveDefinite,  // the matrix (with the current values) is not positive definite
  kFailure,              // CHOLMOD failed otherwise (out of memory, invalid input)
};

class SparseCholesky {
 public:
  // A simplicial factorization factors the matrix permuted here, once per pattern, instead of by
  // CHOLMOD at every factorization: bit for bit the same factor and solutions, 10% less time in
  // iRRR. `permute_once` false leaves the permuting to CHOLMOD (for the test that they agree).
  explicit SparseCholesky(bool permute_once = true);
  ~SparseCholesky();
  SparseCholesky(const SparseCholesky&) = delete;
  SparseCholesky& operator=(const SparseCholesky&) = delete;

  // Sets the pattern of a symmetric n x n matrix by its upper triangle: column c holds the
  // entries column_starts[c] .. column_starts[c+1]-1 with the row indices given (ascending, each
  // <= c). Drops the previous pattern, values and analysis.
  void SetPattern(int n,
                  const std::vector<int>& column_starts,
                  const std::vector<int>& row_indices);

  int size() const;
  int num_nonzeros() const;

  // The matrix values in pattern order; the caller writes them before each Factorize.
  double* mutable_values();

  // Factorizes the current values. On failure `message` (if not null) receives a sentence.
  LinearSolverStatus Factorize(std::string* message);

  // Solves A x = b with the last successful factorization. Returns false (x untouched) if there
  // is none or CHOLMOD fails.
  bool Solve(const Eigen::VectorXd& b, Eigen::VectorXd* x);
  // The same for several right-hand sides at once (the columns of b).
  bool Solve(const Eigen::MatrixXd& b, Eigen::MatrixXd* x);

  int num_analyses() const { return num_analyses_; }              // symbolic analyses so far
  int num_factorizations() const { return num_factorizations_; }  // numeric factorizations so far
  double factor_nonzeros() const;
  // Whether the current analysis factors a matrix permuted here (see the constructor).
  bool permuted_once() const;  // entries of L, 0 before analysis

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  int num_analyses_ = 0;
  int num_factorizations_ = 0;
};

}  // namespace irrr

#endif  // IRRR_CORE_SPARSE_CHOLESKY_H_
