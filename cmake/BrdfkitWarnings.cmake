# Warning flags for brdfkit's own targets (not for consumers).
add_library(brdfkit_warnings INTERFACE)
target_compile_options(brdfkit_warnings INTERFACE
  -Wall -Wextra -Wpedantic -Wnon-virtual-dtor
  $<$<CXX_COMPILER_ID:GNU>:-Wshadow=local>
  # GCC 12 reports false -Wrestrict overlaps inside std::string's operator+
  # at -O2 (GCC bug 105329).
  $<$<CXX_COMPILER_ID:GNU>:-Wno-restrict>
  # In a unity build every source is an included file, and GCC warns of any
  # class there with a member of a type from its anonymous namespace, as it
  # would in a header (each source's own types are meant to be local).
  $<$<AND:$<CXX_COMPILER_ID:GNU>,$<BOOL:${CMAKE_UNITY_BUILD}>>:-Wno-subobject-linkage>
  $<$<BOOL:${BRDFKIT_WERROR}>:-Werror>
  # sqrt without errno: GCC then vectorises the batch kernels of brdf/batch.h
  # (with errno it branches around every sqrt). Values are the same: brdfkit
  # reads errno only after I/O calls.
  $<$<CXX_COMPILER_ID:GNU,Clang>:-fno-math-errno>)
if(BRDFKIT_SANITIZE)
  target_compile_options(brdfkit_warnings INTERFACE -fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=all
    $<$<CXX_COMPILER_ID:Clang>:-fsanitize-ignorelist=${PROJECT_SOURCE_DIR}/cmake/ubsan_ignore.txt>)
  target_link_options(brdfkit_warnings INTERFACE -fsanitize=address,undefined)
endif()
