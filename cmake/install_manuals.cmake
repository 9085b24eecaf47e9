# Run by `cmake --install` and cpack (cmake/packaging.cmake sets SLAM_MANUAL_ENTRIES,
# SLAM_SOURCE_DIR, SLAM_MAN_DIR and SLAM_DATA_DIR): a manual page for each program from its
# --help and --version (help2man), gzip -9n as Debian wants, in DESTDIR/PREFIX/share/man/man1.
# Defaults that name the source tree (--robot, --web-root) name the installed files instead.
find_program(SLAM_HELP2MAN help2man)
if(NOT SLAM_HELP2MAN)
  message(WARNING "help2man is missing: no manual pages (scripts/deps --package installs it)")
  return()
endif()
set(man_dir "$ENV{DESTDIR}${CMAKE_INSTALL_PREFIX}/${SLAM_MAN_DIR}")
set(data_dir "${CMAKE_INSTALL_PREFIX}/${SLAM_DATA_DIR}")
file(MAKE_DIRECTORY "${man_dir}")
foreach(entry ${SLAM_MANUAL_ENTRIES})
  string(REPLACE "|" ";" fields "${entry}")
  list(GET fields 0 binary)
  list(GET fields 1 program)
  list(GET fields 2 summary)
  execute_process(COMMAND ${SLAM_HELP2MAN} --no-info --section=1 "--name=${summary}" ${binary}
                  OUTPUT_VARIABLE page ERROR_VARIABLE errors RESULT_VARIABLE status)
  if(NOT status EQUAL 0)
    message(FATAL_ERROR "help2man ${binary} failed (${status}): ${errors}")
  endif()
  # help2man escapes hyphens for groff.
  string(REPLACE "-" "\\-" escaped_source_dir "${SLAM_SOURCE_DIR}")
  string(REPLACE "-" "\\-" escaped_data_dir "${data_dir}")
  string(REPLACE "${escaped_source_dir}/" "${escaped_data_dir}/" page "${page}")
  string(REPLACE "${SLAM_SOURCE_DIR}/" "${data_dir}/" page "${page}")
  file(WRITE "${man_dir}/${program}.1" "${page}")
  execute_process(COMMAND gzip -9nf "${man_dir}/${program}.1" RESULT_VARIABLE status)
  if(NOT status EQUAL 0)
    message(FATAL_ERROR "gzip ${man_dir}/${program}.1 failed: ${status}")
  endif()
  message(STATUS "Installing: ${man_dir}/${program}.1.gz")
endforeach()
