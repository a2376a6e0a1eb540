# Robustness stages in ctest (included from tests/CMakeLists.txt), so the
# README's test command runs them:
#  - sanitizers (BRDFKIT_SANITIZER_SUITE): the whole test suite built and
#    run with ASan + UBSan in <build>/asan (SanitizeSuite.cmake);
#  - fuzz_build, fuzz_<reader>: libFuzzer targets (tests/fuzz) built with
#    clang in <build>/fuzz and each run for BRDFKIT_FUZZ_SECONDS over its
#    seed corpus (FuzzBuild.cmake, FuzzRun.cmake).
# The sanitizer tree itself has them off (BRDFKIT_ROBUSTNESS_TESTS=OFF).
option(BRDFKIT_ROBUSTNESS_TESTS "Add the sanitizer suite and the fuzzers to ctest" ${BRDFKIT_TOP_LEVEL})
set(BRDFKIT_FUZZ_SECONDS 20 CACHE STRING "Seconds each fuzz target runs under ctest")

# The sanitizer tree is built with clang: its ASan + UBSan compiles of this
# code take about the CPU time of GCC's -O3 ones, where GCC's take 3x
# (UBSan's null, alignment and object-size checks on Eigen code).
option(BRDFKIT_SANITIZER_SUITE "With BRDFKIT_ROBUSTNESS_TESTS: the ASan/UBSan suite stage" ON)
find_program(BRDFKIT_CLANGXX NAMES clang++ clang++-14)

if(BRDFKIT_ROBUSTNESS_TESTS AND BRDFKIT_SANITIZER_SUITE AND NOT BRDFKIT_SANITIZE)
  add_test(NAME sanitizers
    COMMAND ${CMAKE_COMMAND} -DSOURCE_DIR=${PROJECT_SOURCE_DIR} -DBINARY_DIR=${PROJECT_BINARY_DIR}/asan
            -DCXX=${BRDFKIT_CLANGXX} -P ${PROJECT_SOURCE_DIR}/cmake/SanitizeSuite.cmake)
  # Started first (ctest runs the longest tests first once it knows them).
  set_tests_properties(sanitizers PROPERTIES TIMEOUT 3600 COST 1000)
endif()

if(BRDFKIT_ROBUSTNESS_TESTS AND NOT BRDFKIT_SANITIZE)
  set(_fuzz_tree ${PROJECT_BINARY_DIR}/fuzz)
  add_test(NAME fuzz_build
    COMMAND ${CMAKE_COMMAND} -DSOURCE_DIR=${PROJECT_SOURCE_DIR}/tests/fuzz -DBINARY_DIR=${_fuzz_tree}
            -DCXX=${BRDFKIT_CLANGXX} -DMAIN_BUILD=${PROJECT_BINARY_DIR} -P ${PROJECT_SOURCE_DIR}/cmake/FuzzBuild.cmake)
  set_tests_properties(fuzz_build PROPERTIES FIXTURES_SETUP fuzz_targets TIMEOUT 900 COST 500)
  set(_targets merl rgl utia astm csv instrument)
  if(EXISTS ${PROJECT_SOURCE_DIR}/cli/scene.h)
    list(APPEND _targets scene)
  endif()
  foreach(_t ${_targets})
    set(_dict ${PROJECT_SOURCE_DIR}/tests/fuzz/${_t}.dict)
    if(NOT EXISTS ${_dict})
      set(_dict "")
    endif()
    # The three measured-data readers share the stage time of one.
    set(_seconds ${BRDFKIT_FUZZ_SECONDS})
    if(_t MATCHES "^(rgl|utia|astm)$")
      math(EXPR _seconds "(${BRDFKIT_FUZZ_SECONDS} + 2) / 3")
    endif()
    add_test(NAME fuzz_${_t}
      COMMAND ${CMAKE_COMMAND} -DEXE=${_fuzz_tree}/fuzz_${_t} -DCORPUS=${PROJECT_SOURCE_DIR}/tests/fuzz/corpus/${_t}
              -DWORK_DIR=${_fuzz_tree}/run_${_t} -DSECONDS=${_seconds} -DDICT=${_dict}
              -P ${PROJECT_SOURCE_DIR}/cmake/FuzzRun.cmake)
    set_tests_properties(fuzz_${_t} PROPERTIES FIXTURES_REQUIRED fuzz_targets TIMEOUT 600 COST 100)
  endforeach()
endif()
