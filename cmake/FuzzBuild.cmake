# ctest stage: configures and builds the libFuzzer targets (tests/fuzz) with
# clang in their own tree. -DSOURCE_DIR=<tests/fuzz> -DBINARY_DIR=<tree> -DCXX=<clang++>
# -DMAIN_BUILD=<main tree> (for the scene parser's libraries)
if(NOT CXX)
  message(FATAL_ERROR "fuzz_build: clang++ not found (Debian: apt-get install clang libclang-rt-14-dev; .ci/setup does it)")
endif()
execute_process(COMMAND ${CMAKE_COMMAND} -S ${SOURCE_DIR} -B ${BINARY_DIR} -DCMAKE_CXX_COMPILER=${CXX}
                        -DBRDFKIT_MAIN_BUILD=${MAIN_BUILD}
                RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "fuzz_build: configuring ${BINARY_DIR} failed")
endif()
execute_process(COMMAND ${CMAKE_COMMAND} --build ${BINARY_DIR} -j 2 RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "fuzz_build: building the fuzz targets failed")
endif()
