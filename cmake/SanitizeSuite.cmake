# ctest stage: the whole test suite built with AddressSanitizer and
# UndefinedBehaviorSanitizer (BRDFKIT_SANITIZE) by clang in its own tree,
# then run. -DSOURCE_DIR=<repo> -DBINARY_DIR=<tree> -DCXX=<clang++> [-DJOBS=2]
if(NOT JOBS)
  set(JOBS 2)
endif()
if(NOT CXX)
  message(FATAL_ERROR "sanitizers: clang++ not found (Debian: apt-get install clang libclang-rt-14-dev; .ci/setup does it)")
endif()
# -O1, the optimisation ASan recommends. Warnings are reported, not fatal:
# the warning set is GCC's.
execute_process(COMMAND ${CMAKE_COMMAND} -S ${SOURCE_DIR} -B ${BINARY_DIR} -DCMAKE_BUILD_TYPE=Release
                        -DCMAKE_CXX_COMPILER=${CXX} "-DCMAKE_CXX_FLAGS_RELEASE=-O1 -DNDEBUG"
                        -DBRDFKIT_SANITIZE=ON -DBRDFKIT_WERROR=OFF -DBRDFKIT_BUILD_BENCH=OFF -DBRDFKIT_INSTALL=OFF
                        -DBRDFKIT_ROBUSTNESS_TESTS=OFF -DBRDFKIT_PYTHON=OFF -DBRDFKIT_TEST_SHARDS=4
                RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "sanitizers: configuring ${BINARY_DIR} failed")
endif()
execute_process(COMMAND ${CMAKE_COMMAND} --build ${BINARY_DIR} -j ${JOBS} RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "sanitizers: building ${BINARY_DIR} failed")
endif()
# halt_on_error: the first finding fails its test; leaks are findings too.
set(ENV{ASAN_OPTIONS} "halt_on_error=1:detect_leaks=1:abort_on_error=0")
set(ENV{UBSAN_OPTIONS} "halt_on_error=1:print_stacktrace=1")
# The tests tests/sanitizer_skips.txt names are left out: those of its
# [covered] section run no line and no branch of brdfkit's sources that the
# tests run here do not (tests/sanitizer_skips_check.py measures it), those
# of its [cost] section are left out for their cost. Names with a dot are
# GoogleTest names (patterns allowed), the rest ctest stages. The test
# executables run in shards (gtest's own sharding, BRDFKIT_TEST_SHARDS),
# which read the filter. install_consumer needs the install target, which
# this tree does not make.
file(STRINGS ${SOURCE_DIR}/tests/sanitizer_skips.txt _lines)
set(_gtest "")
set(_stages "install_consumer")
foreach(_line IN LISTS _lines)
  string(REGEX REPLACE "#.*" "" _name "${_line}")
  string(STRIP "${_name}" _name)
  if(_name MATCHES "^\\[")
    # a section header ([covered], [cost])
  elseif(_name MATCHES "\\.")
    list(APPEND _gtest "${_name}")
  elseif(NOT _name STREQUAL "")
    string(APPEND _stages "|^${_name}$")
  endif()
endforeach()
list(JOIN _gtest ":" _gtest)
set(ENV{GTEST_FILTER} "-${_gtest}")
execute_process(COMMAND ${CMAKE_CTEST_COMMAND} --test-dir ${BINARY_DIR} --output-on-failure -j ${JOBS}
                        -E "${_stages}"
                RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "sanitizers: the test suite failed under ASan/UBSan (tree ${BINARY_DIR})")
endif()
