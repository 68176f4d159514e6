#include "core/sparse_cholesky.h"

#include <cholmod.h>

#include <algorithm>
#include <mutex>
#include <vector>

namespace irrr {
namespace {

// CHOLMOD's supernodal kernels call BLAS and LAPACK, and Debian's serial OpenBLAS keeps working
// buffers of its own that two threads calling it at once share: concurrent supernodal
// factorizations then return other numbers (seen as 3D decisions that differed between one and
// two threads). Supernodal numerics therefore take this lock; simplicial ones call no BLAS and run
// side by side. Core starts no threads; the lock only makes concurrent callers safe.
std::mutex& BlasMutex() {
  static std::mutex mutex;
  return mutex;
}

// Holds the lock while `factor` is supernodal.
class BlasLock {
 public:
  explicit BlasLock(const cholmod_factor* factor) {
    if (factor != nullptr && factor->is_super) lock_ = std::unique_lock<std::mutex>(BlasMutex());
  }

 private:
  std::unique_lock<std::mutex> lock_;
};

}  // namespace

struct SparseCholesky::Impl {
  cholmod_common common;
  cholmod_sparse* matrix = nullptr;
  cholmod_factor* factor = nullptr;
  // The symbolic analysis alone. A simplicial factorization starts from a copy of it: CHOLMOD
  // would refactorize a simplicial numeric factor in place in other arithmetic (LL' directly,
  // where the first factorization computes LDL' and converts), so results would depend on what
  // came before; from the copy a factorization is a function of the matrix alone.
  cholmod_factor* symbolic = nullptr;
  bool factorized = false;
  // Simplicial factors: CHOLMOD would permute the upper triangle with two transposes at every
  // factorization (10% of iRRR's time). Instead the matrix is permuted here once per pattern:
  // `permuted` holds triu(P A P') with sorted rows, each value's place in it is in
  // `permuted_index`, and `symbolic` is the analysis of `permuted` in its natural order, so
  // CHOLMOD factorizes the very matrix it would have built (the same arithmetic, bit for bit)
  // without building it. `permutation[k]` is the original index of permuted row k.
  bool permute_once = true;
  cholmod_sparse* permuted = nullptr;
  std::vector<int> permuted_index;
  std::vector<int> permutation;

  Impl() {
    cholmod_start(&common);
    // Errors come back through common.status; CHOLMOD must not print.
    common.print = 0;
    common.error_handler = nullptr;
    // One AMD ordering with a weighted postorder: the nested-dissection alternatives cost more to
    // compute than they save on pose graphs of this size, and one method keeps analysis cheap.
    common.nmethods = 1;
    common.method[0].ordering = CHOLMOD_AMD;
    common.postorder = 1;
    // Simplicial or supernodal by CHOLMOD's own flop count: pose graphs of a few thousand 2D
    // poses factorize twice as fast simplicially, while 3D and larger ones gain from supernodes
    // (irrr-bench-optimizer). final_ll makes the simplicial factor LL' as well, so that an
    // indefinite matrix is reported as such (an LDL' factor would accept it).
    common.supernodal = CHOLMOD_AUTO;
    common.final_ll = 1;
  }

  ~Impl() {
    FreeAll();
    cholmod_finish(&common);
  }

  void FreeAll() {
    if (factor != nullptr) cholmod_free_factor(&factor, &common);
    if (symbolic != nullptr) cholmod_free_factor(&symbolic, &common);
    if (matrix != nullptr) cholmod_free_sparse(&matrix, &common);
    if (permuted != nullptr) cholmod_free_sparse(&permuted, &common);
    permuted_index.clear();
    permutation.clear();
    factorized = false;
  }

  // With `symbolic` a simplicial analysis of `matrix` (fill-reducing order P), builds `permuted`
  // = triu(P A P') and replaces `symbolic` by the natural-order analysis of it. Returns false
  // (everything as it was) if CHOLMOD fails or judges the permuted matrix otherwise.
  bool PermuteOnce() {
    const int n = static_cast<int>(matrix->nrow);
    const int* column_starts = static_cast<const int*>(matrix->p);
    const int* rows = static_cast<const int*>(matrix->i);
    const int* order = static_cast<const int*>(symbolic->Perm);
    std::vector<int> new_index(n);
    for (int k = 0; k < n; ++k) new_index[order[k]] = k;
    // Each entry's place in triu(P A P'), then columns filled in row order (a counting sort by
    // row, then by column): sorted rows, the layout CHOLMOD's transposes produce.
    const int nonzeros = column_starts[n];
    std::vector<int> new_row(nonzeros);
    std::vector<int> new_column(nonzeros);
    std::vector<int> column_start(n + 1, 0);
    std::vector<int> row_start(n + 1, 0);
    for (int c = 0; c < n; ++c) {
      for (int k = column_starts[c]; k < column_starts[c + 1]; ++k) {
        const int a = new_index[rows[k]];
        const int b = new_index[c];
        new_row[k] = std::min(a, b);
        new_column[k] = std::max(a, b);
        ++column_start[new_column[k] + 1];
        ++row_start[new_row[k] + 1];
      }
    }
    for (int k = 0; k < n; ++k) {
      column_start[k + 1] += column_start[k];
      row_start[k + 1] += row_start[k];
    }
    std::vector<int> by_row(nonzeros);
    for (int k = 0; k < nonzeros; ++k) by_row[row_start[new_row[k]]++] = k;
    cholmod_sparse* out = cholmod_allocate_sparse(n,
                                                  n,
                                                  nonzeros,
                                                  /*sorted=*/1,
                                                  /*packed=*/1,
                                                  /*stype=*/1,
                                                  CHOLMOD_REAL,
                                                  &common);
    if (out == nullptr) return false;
    std::copy(column_start.begin(), column_start.end(), static_cast<int*>(out->p));
    int* out_rows = static_cast<int*>(out->i);
    std::vector<int> index(nonzeros);
    for (int k : by_row) {
      const int position = column_start[new_column[k]]++;
      out_rows[position] = new_row[k];
      index[k] = position;
    }
    std::fill_n(static_cast<double*>(out->x), nonzeros, 0.0);

    // The natural-order analysis of the permuted pattern (no postorder: the order stays).
    const auto method = common.method[0];
    const int postorder = common.postorder;
    common.method[0].ordering = CHOLMOD_NATURAL;
    common.postorder = 0;
    cholmod_factor* natural = cholmod_analyze(out, &common);
    common.method[0] = method;
    common.postorder = postorder;
    if (natural == nullptr || natural->is_super || natural->ordering != CHOLMOD_NATURAL) {
      if (natural != nullptr) cholmod_free_factor(&natural, &common);
      cholmod_free_sparse(&out, &common);
      return false;
    }
    permutation.assign(order, order + n);
    cholmod_free_factor(&symbolic, &common);
    symbolic = natural;
    permuted = out;
    permuted_index = std::move(index);
    return true;
  }
};

SparseCholesky::SparseCholesky(bool permute_once) : impl_(std::make_unique<Impl>()) {
  impl_->permute_once = permute_once;
}
SparseCholesky::~SparseCholesky() = default;

void SparseCholesky::SetPattern(int n,
                                const std::vector<int>& column_starts,
                                const std::vector<int>& row_indices) {
  impl_->FreeAll();
  const size_t nonzeros = row_indices.size();
  impl_->matrix = cholmod_allocate_sparse(n,
                                          n,
                                          nonzeros,
                                          /*sorted=*/1,
                                          /*packed=*/1,
                                          /*stype=*/1,
                                          CHOLMOD_REAL,
                                          &impl_->common);
  if (impl_->matrix == nullptr) return;  // reported by Factorize
  std::copy(column_starts.begin(), column_starts.end(), static_cast<int*>(impl_->matrix->p));
  std::copy(row_indices.begin(), row_indices.end(), static_cast<int*>(impl_->matrix->i));
  std::fill_n(static_cast<double*>(impl_->matrix->x), nonzeros, 0.0);
}

int SparseCholesky::size() const {
  return impl_->matrix == nullptr ? 0 : static_cast<int>(impl_->matrix->nrow);
}

int SparseCholesky::num_nonzeros() const {
  return impl_->matrix == nullptr ? 0 : static_cast<int*>(impl_->matrix->p)[impl_->matrix->ncol];
}

double* SparseCholesky::mutable_values() {
  return impl_->matrix == nullptr ? nullptr : static_cast<double*>(impl_->matrix->x);
}

bool SparseCholesky::permuted_once() const { return impl_->permuted != nullptr; }

double SparseCholesky::factor_nonzeros() const {
  if (impl_->factor == nullptr) return 0.0;
  return impl_->common.lnz;
}

LinearSolverStatus SparseCholesky::Factorize(std::string* message) {
  impl_->factorized = false;
  if (impl_->matrix == nullptr) {
    if (message != nullptr) *message = "CHOLMOD: no matrix (allocation failed or no pattern set)";
    return LinearSolverStatus::kFailure;
  }
  if (impl_->symbolic == nullptr) {
    impl_->symbolic = cholmod_analyze(impl_->matrix, &impl_->common);
    if (impl_->symbolic == nullptr) {
      if (message != nullptr) {
        *message = "CHOLMOD analysis failed (status " + std::to_string(impl_->common.status) + ")";
      }
      return LinearSolverStatus::kFailure;
    }
    ++num_analyses_;
    if (impl_->permute_once && !impl_->symbolic->is_super) impl_->PermuteOnce();
  }
  cholmod_sparse* input = impl_->matrix;
  if (impl_->permuted != nullptr) {
    const double* values = static_cast<const double*>(impl_->matrix->x);
    double* permuted_values = static_cast<double*>(impl_->permuted->x);
    const size_t nonzeros = impl_->permuted_index.size();
    for (size_t k = 0; k < nonzeros; ++k) permuted_values[impl_->permuted_index[k]] = values[k];
    input = impl_->permuted;
  }
  // A supernodal factor is refactorized in place (always LL', the same arithmetic each time, and
  // no reallocation of its values); a simplicial one starts from a copy of the analysis.
  if (impl_->factor == nullptr || !impl_->symbolic->is_super) {
    if (impl_->factor != nullptr) cholmod_free_factor(&impl_->factor, &impl_->common);
    impl_->factor = cholmod_copy_factor(impl_->symbolic, &impl_->common);
    if (impl_->factor == nullptr) {
      if (message != nullptr) *message = "CHOLMOD: out of memory copying the symbolic factor";
      return LinearSolverStatus::kFailure;
    }
  }
  int ok = 0;
  {
    const BlasLock lock(impl_->factor);
    ok = cholmod_factorize(input, impl_->factor, &impl_->common);
  }
  ++num_factorizations_;
  if (impl_->common.status == CHOLMOD_NOT_POSDEF) {
    if (message != nullptr) {
      *message = "matrix not positive definite (CHOLMOD stopped at column " +
                 std::to_string(impl_->factor->minor) + ")";
    }
    return LinearSolverStatus::kNotPositiveDefinite;
  }
  if (!ok || impl_->common.status < CHOLMOD_OK) {
    if (message != nullptr) {
      *message =
          "CHOLMOD factorization failed (status " + std::to_string(impl_->common.status) + ")";
    }
    return LinearSolverStatus::kFailure;
  }
  impl_->factorized = true;
  return LinearSolverStatus::kSuccess;
}

bool SparseCholesky::Solve(const Eigen::VectorXd& b, Eigen::VectorXd* x) {
  Eigen::MatrixXd solution;
  if (!Solve(Eigen::MatrixXd(b), &solution)) return false;
  *x = solution.col(0);
  return true;
}

bool SparseCholesky::Solve(const Eigen::MatrixXd& b, Eigen::MatrixXd* x) {
  if (!impl_->factorized || b.rows() != size() || b.cols() < 1) return false;
  // A dense header over b's storage (column-major, as CHOLMOD's): CHOLMOD reads it and allocates
  // the solution itself. With a permuted matrix, b's rows are permuted here and x's back (what
  // CHOLMOD does otherwise).
  const std::vector<int>& permutation = impl_->permutation;
  Eigen::MatrixXd permuted_b;
  if (!permutation.empty()) {
    permuted_b.resize(b.rows(), b.cols());
    for (Eigen::Index k = 0; k < b.rows(); ++k) permuted_b.row(k) = b.row(permutation[k]);
  }
  cholmod_dense rhs{};
  rhs.nrow = static_cast<size_t>(b.rows());
  rhs.ncol = static_cast<size_t>(b.cols());
  rhs.nzmax = rhs.nrow * rhs.ncol;
  rhs.d = rhs.nrow;
  rhs.x = const_cast<double*>(permutation.empty() ? b.data() : permuted_b.data());
  rhs.z = nullptr;
  rhs.xtype = CHOLMOD_REAL;
  rhs.dtype = CHOLMOD_DOUBLE;
  cholmod_dense* solution = nullptr;
  {
    const BlasLock lock(impl_->factor);
    solution = cholmod_solve(CHOLMOD_A, impl_->factor, &rhs, &impl_->common);
  }
  if (solution == nullptr) return false;
  x->resize(b.rows(), b.cols());
  const Eigen::Map<const Eigen::MatrixXd> values(
      static_cast<const double*>(solution->x), b.rows(), b.cols());
  if (permutation.empty()) {
    *x = values;
  } else {
    for (Eigen::Index k = 0; k < b.rows(); ++k) x->row(permutation[k]) = values.row(k);
  }
  cholmod_free_dense(&solution, &impl_->common);
  return true;
}

}  // namespace irrr
