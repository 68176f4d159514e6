#include "core/sparse_cholesky.h"

#include <cholmod.h>

#include <algorithm>
#include <mutex>

// libgomp's, declared here so that no compiler's omp.h is needed (CHOLMOD links libgomp).
extern "C" void omp_set_max_active_levels(int max_levels);

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

// CHOLMOD's supernodal factorization opens OpenMP parallel regions of a fixed thread count (its
// compile-time CHOLMOD_OMP_NUM_THREADS, which OMP_NUM_THREADS does not override). On pose graphs
// their start and wake-ups cost more than they save: a 3D iRRR run spent 40% of its time in them
// and took 2.3 times as long. Parallelism belongs to the caller (independent solves on its pool),
// so each calling thread runs CHOLMOD's regions with one thread: a thread's max-active-levels of
// 0 makes every region it opens inactive. The setting is per thread in libgomp.
void SerialOpenMpRegions() {
  thread_local bool done = false;
  if (!done) {
    omp_set_max_active_levels(0);
    done = true;
  }
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
    factorized = false;
  }
};

SparseCholesky::SparseCholesky() : impl_(std::make_unique<Impl>()) {}
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
  SerialOpenMpRegions();
  if (impl_->symbolic == nullptr) {
    impl_->symbolic = cholmod_analyze(impl_->matrix, &impl_->common);
    if (impl_->symbolic == nullptr) {
      if (message != nullptr) {
        *message = "CHOLMOD analysis failed (status " + std::to_string(impl_->common.status) + ")";
      }
      return LinearSolverStatus::kFailure;
    }
    ++num_analyses_;
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
    ok = cholmod_factorize(impl_->matrix, impl_->factor, &impl_->common);
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
  if (!impl_->factorized || b.size() != size()) return false;
  // A dense header over b's storage: CHOLMOD reads it and allocates the solution itself.
  cholmod_dense rhs{};
  rhs.nrow = static_cast<size_t>(b.size());
  rhs.ncol = 1;
  rhs.nzmax = rhs.nrow;
  rhs.d = rhs.nrow;
  rhs.x = const_cast<double*>(b.data());
  rhs.z = nullptr;
  rhs.xtype = CHOLMOD_REAL;
  rhs.dtype = CHOLMOD_DOUBLE;
  cholmod_dense* solution = nullptr;
  {
    const BlasLock lock(impl_->factor);
    solution = cholmod_solve(CHOLMOD_A, impl_->factor, &rhs, &impl_->common);
  }
  if (solution == nullptr) return false;
  x->resize(b.size());
  std::copy_n(static_cast<const double*>(solution->x), b.size(), x->data());
  cholmod_free_dense(&solution, &impl_->common);
  return true;
}

}  // namespace irrr
