// CHOLMOD's parallel regions, run in the calling thread.
//
// Debian's CHOLMOD is built with OpenMP: its supernodal factorization opens two parallel regions
// per supernode, with a thread count fixed when it was compiled (OMP_NUM_THREADS does not change
// it). An iRRR step refactorizes many times, and on pose graphs every region costs more than it
// saves. Even an inactive region (one thread) costs libgomp a team allocation and a futex wake:
// a 20 000-pose fleet file ran in half the time without them. Core runs no threads (parallelism
// belongs to its caller), so this is the entry point GCC compiles `#pragma omp parallel` to,
// defined to run the region's body once in the thread that opened it: what an OpenMP region with a
// team of one does, by the specification (inside it omp_get_num_threads() is 1 and
// omp_get_thread_num() is 0, since no team was started).
//
// A program that links core resolves libcholmod's call here rather than in libgomp: the linker
// exports a definition in the executable that a shared library it links refers to, and the
// dynamic linker searches the executable first. core/CMakeLists.txt makes every program that
// links core keep this file (-u GOMP_parallel). The program's own OpenMP regions, if it had any,
// would run serially too.

extern "C" void GOMP_parallel(void (*body)(void*),
                              void* data,
                              unsigned /*num_threads*/,
                              unsigned /*flags*/) {
  body(data);
}
