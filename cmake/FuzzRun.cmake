# ctest stage: runs one libFuzzer target for a bounded time over its seed
# corpus. New inputs go to WORK_DIR/corpus (the repository's corpus is only
# read); a crash leaves its input in WORK_DIR and fails the test.
# -DEXE=<fuzzer> -DCORPUS=<seed dir> -DWORK_DIR=<dir> -DSECONDS=<n> [-DDICT=<file>]
file(MAKE_DIRECTORY ${WORK_DIR}/corpus)
# A fixed seed: the same mutations in every run, so a CI result is
# reproducible (run the fuzzer by hand with other seeds to explore further).
set(_args -seed=1 -max_total_time=${SECONDS} -timeout=20 -rss_limit_mb=3072 -print_final_stats=1
          -artifact_prefix=${WORK_DIR}/)
if(DICT)
  list(APPEND _args -dict=${DICT})
endif()
execute_process(COMMAND ${EXE} ${_args} ${WORK_DIR}/corpus ${CORPUS}
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE out)
string(REGEX MATCH "Done [0-9]+ runs in [0-9]+ second" done "${out}")
string(REGEX MATCH "stat::number_of_executed_units: [0-9]+" units "${out}")
string(REGEX MATCHALL "cov: [0-9]+ ft: [0-9]+ corp: [0-9]+/[0-9]+[a-zA-Z]*" covs "${out}")
set(cov "")
if(covs)
  list(GET covs -1 cov)  # the final line
endif()
if(NOT rc EQUAL 0)
  message("${out}")
  message(FATAL_ERROR "fuzzer ${EXE} failed (exit ${rc}); the input is in ${WORK_DIR}")
endif()
message(STATUS "${EXE}: ${done}s; ${units}; ${cov}")
