# Runs a libFuzzer target for CTest (tests/fuzz/CMakeLists.txt):
#   cmake -DFUZZER=<binary> -DSEEDS=<dir> -DSCRATCH=<dir> -DSECONDS=<n> -P run_fuzzer.cmake
# SECONDS 0: every seed once. Otherwise a fresh copy of the seeds in SCRATCH/corpus is fuzzed for
# SECONDS (new inputs land there, not in SEEDS). Reproducers of crashes go to SCRATCH/artifacts/.
# Fails on the fuzzer's failure (a crash, leak, sanitizer report, timeout or out-of-memory).

file(REMOVE_RECURSE ${SCRATCH})
file(MAKE_DIRECTORY ${SCRATCH}/artifacts)
set(options -rss_limit_mb=2048 -timeout=10 -artifact_prefix=${SCRATCH}/artifacts/)
if(SECONDS EQUAL 0)
  set(run -runs=0 ${SEEDS})
else()
  file(COPY ${SEEDS}/ DESTINATION ${SCRATCH}/corpus)
  set(run -max_total_time=${SECONDS} -print_final_stats=1 ${SCRATCH}/corpus)
endif()
execute_process(COMMAND ${FUZZER} ${options} ${run} RESULT_VARIABLE result)
if(NOT result EQUAL 0)
  message(FATAL_ERROR "${FUZZER} failed (${result}); reproducers in ${SCRATCH}/artifacts/")
endif()
