# Read by cpack before it makes a package (CPACK_PROJECT_CONFIG_FILE, set in
# cmake/packaging.cmake): a Debian package is refused without the page's plots or the manual
# pages rather than shipped broken.
if(CPACK_GENERATOR STREQUAL "DEB")
  file(READ "${CPACK_SLAM_COPYRIGHT_FILE}" copyright)
  if(NOT EXISTS "${CPACK_SLAM_UPLOT_LICENSE_FILE}" OR NOT copyright MATCHES "License: Expat\n ")
    message(FATAL_ERROR
            "web/node_modules/uplot was missing when the build was configured: the page would "
            "have no plots. Run scripts/deps, configure again, then cpack.")
  endif()
  find_program(SLAM_HELP2MAN help2man)
  if(NOT SLAM_HELP2MAN)
    message(FATAL_ERROR "help2man is missing: the package would have no manual pages "
                        "(scripts/deps --package installs it)")
  endif()
endif()
