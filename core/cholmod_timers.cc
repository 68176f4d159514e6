// CHOLMOD's timers, stopped.
//
// Debian's CHOLMOD is compiled with its timers on: the supernodal factorization reads the clock
// before and after every BLAS call it makes (SuiteSparse_time, a clock_gettime), to add the time
// to statistics in cholmod_common that core never reads. On a pose graph's small supernodes those
// reads were 3.6% of a 20 000-pose fleet file's run. This definition, found before
// libsuitesparseconfig's for the same reason as serial_openmp.cc's, returns 0: the statistics stay
// at zero and nothing else changes (CHOLMOD decides nothing by them). core/CMakeLists.txt makes
// every program that links core keep it (-u SuiteSparse_time).

extern "C" double SuiteSparse_time(void) { return 0.0; }
