# One place for the warnings applied to our own targets (third-party headers come in as SYSTEM).
function(slam_set_warnings target)
  target_compile_options(${target} PRIVATE
    -Wall -Wextra -Wpedantic -Wconversion -Wsign-conversion -Wshadow -Wnon-virtual-dtor
    -Wold-style-cast -Woverloaded-virtual)
  # GCC 12 reports -Wrestrict false positives inside libstdc++'s std::string at -O2 (GCC bug 105329).
  if(CMAKE_CXX_COMPILER_ID STREQUAL "GNU" AND CMAKE_CXX_COMPILER_VERSION VERSION_LESS 13)
    target_compile_options(${target} PRIVATE -Wno-restrict)
  endif()
  # Clang checks the mutex annotations of engine/thread_safety.hpp (GCC has no such analysis).
  if(CMAKE_CXX_COMPILER_ID STREQUAL "Clang")
    target_compile_options(${target} PRIVATE -Wthread-safety)
  endif()
  if(SLAM_WERROR)
    target_compile_options(${target} PRIVATE -Werror)
  endif()
endfunction()
