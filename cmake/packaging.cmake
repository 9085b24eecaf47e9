# The Debian package (issue 26): `cpack -G DEB` in a build folder, or scripts/package, makes
# slamd_<version>_<arch>.deb with slamd and its systemd service, the tools, the page, the robot
# descriptions and the shipped parameters, manual pages made by help2man, and the files Debian
# wants (copyright, changelog). The package installs under /usr whatever CMAKE_INSTALL_PREFIX is:
# installed programs find their files beside themselves (engine/io/shipped_path.hpp).
include(GNUInstallDirs)
set(SLAM_DEB_DIR ${PROJECT_SOURCE_DIR}/packaging/deb)

# The shipped files, as the source tree holds them (config/ under share/slamd).
install(FILES ${PROJECT_SOURCE_DIR}/config/marxbot.robot.json
              ${PROJECT_SOURCE_DIR}/config/pioneer-lms.robot.json
              ${PROJECT_SOURCE_DIR}/config/lidar.robot.json
              ${PROJECT_SOURCE_DIR}/config/params.default.json
        DESTINATION ${CMAKE_INSTALL_DATADIR}/slamd/config)
install(DIRECTORY ${PROJECT_SOURCE_DIR}/config/params DESTINATION ${CMAKE_INSTALL_DATADIR}/slamd/config
        FILES_MATCHING PATTERN "*.json")

# Manual pages from every program's --help and --version (help2man), at install time.
set(SLAM_MANUAL_PROGRAMS
    "slamd|real-time SLAM server for the marXbot with a map in the browser"
    "slam-sim|write recorded experiments of the virtual marXbot"
    "slam-link|listen to the robot through a source and count what the link decodes"
    "slam-replay|run the SLAM on a recorded experiment or a CARMEN log"
    "slam-evaluate|replay recorded experiments at each ray budget and tabulate them"
    "slam-relations|score trajectories on a benchmark's relations (Freiburg format)"
    "slam-tune|tune the SLAM parameters for each ray budget with an evolution strategy"
    "slamd-load|load slamd with event-stream viewers and REST requests")
set(manual_entries "")
foreach(entry ${SLAM_MANUAL_PROGRAMS})
  string(REPLACE "|" ";" fields "${entry}")
  list(GET fields 0 program)
  list(GET fields 1 summary)
  list(APPEND manual_entries "$<TARGET_FILE:${program}>|${program}|${summary}")
endforeach()
install(CODE "set(SLAM_MANUAL_ENTRIES \"${manual_entries}\")
set(SLAM_SOURCE_DIR \"${SLAM_SOURCE_DIR}\")
set(SLAM_MAN_DIR \"${CMAKE_INSTALL_MANDIR}/man1\")
set(SLAM_DATA_DIR \"${CMAKE_INSTALL_DATADIR}/slamd\")")
install(SCRIPT ${PROJECT_SOURCE_DIR}/cmake/install_manuals.cmake)

# The service: the unit, its options (a conffile), and the maintainer scripts that enable it.
install(FILES ${SLAM_DEB_DIR}/slamd.service DESTINATION /lib/systemd/system)
install(FILES ${SLAM_DEB_DIR}/slamd.default DESTINATION /etc/default RENAME slamd)

# /usr/share/doc/slamd: the copyright (with uPlot's licence, read from web/node_modules) and the
# changelog, compressed as lintian wants (gzip -9n: no name, no time stamp).
set(SLAM_UPLOT_LICENSE_FILE ${PROJECT_SOURCE_DIR}/web/node_modules/uplot/LICENSE)
set(SLAM_UPLOT_COPYRIGHT "unknown: web/node_modules/uplot is missing (scripts/deps installs it)")
set(SLAM_UPLOT_LICENSE " uPlot's licence text was not found when the package was configured.")
if(EXISTS ${SLAM_UPLOT_LICENSE_FILE})
  set_property(DIRECTORY APPEND PROPERTY CMAKE_CONFIGURE_DEPENDS ${SLAM_UPLOT_LICENSE_FILE})
  file(STRINGS ${SLAM_UPLOT_LICENSE_FILE} uplot_lines)
  set(SLAM_UPLOT_LICENSE "")
  set(in_text FALSE)
  foreach(line IN LISTS uplot_lines)
    if(line MATCHES "^Copyright \\(c\\) (.*)$")
      set(SLAM_UPLOT_COPYRIGHT "${CMAKE_MATCH_1}")
      set(in_text TRUE)
    elseif(in_text)
      if(line STREQUAL "")
        string(APPEND SLAM_UPLOT_LICENSE " .\n")
      else()
        string(APPEND SLAM_UPLOT_LICENSE " ${line}\n")
      endif()
    endif()
  endforeach()
  string(REGEX REPLACE "^ \\.\n" "" SLAM_UPLOT_LICENSE "${SLAM_UPLOT_LICENSE}")
  string(REGEX REPLACE "\n$" "" SLAM_UPLOT_LICENSE "${SLAM_UPLOT_LICENSE}")
endif()
configure_file(${SLAM_DEB_DIR}/copyright.in ${CMAKE_BINARY_DIR}/packaging/copyright @ONLY)
set_property(DIRECTORY APPEND PROPERTY CMAKE_CONFIGURE_DEPENDS ${SLAM_DEB_DIR}/changelog)
execute_process(COMMAND gzip -9n -c ${SLAM_DEB_DIR}/changelog
                OUTPUT_FILE ${CMAKE_BINARY_DIR}/packaging/changelog.gz RESULT_VARIABLE gzip_status)
if(NOT gzip_status EQUAL 0)
  message(FATAL_ERROR "gzip ${SLAM_DEB_DIR}/changelog failed: ${gzip_status}")
endif()
install(FILES ${CMAKE_BINARY_DIR}/packaging/copyright ${CMAKE_BINARY_DIR}/packaging/changelog.gz
        DESTINATION ${CMAKE_INSTALL_DATADIR}/doc/slamd)

# A version without its changelog entry would ship a package whose changelog says otherwise.
file(STRINGS ${SLAM_DEB_DIR}/changelog changelog_head LIMIT_COUNT 1)
if(NOT changelog_head MATCHES "^slamd \\(${PROJECT_VERSION}\\) ")
  message(WARNING "packaging/deb/changelog begins with \"${changelog_head}\", not version "
                  "${PROJECT_VERSION}: add an entry for it before making a package")
endif()

file(WRITE ${CMAKE_BINARY_DIR}/packaging/conffiles "/etc/default/slamd\n")

set(CPACK_GENERATOR DEB)
set(CPACK_PACKAGE_NAME slamd)
set(CPACK_PACKAGE_VERSION ${PROJECT_VERSION})
set(CPACK_PACKAGING_INSTALL_PREFIX /usr)
set(CPACK_STRIP_FILES ON)
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY "real-time 2D SLAM server for the marXbot robot")
# Lines of at most 79 characters (lintian: extended-description-line-too-long beyond 80).
set(CPACK_PACKAGE_DESCRIPTION
    "slamd maps the marXbot's rotating infrared scanner in real time (FastSLAM 2.0
on an occupancy grid, its cost set by a ray budget) from the robot's CAN
frames (slcan, SocketCAN, UDP, a candump log) or from a virtual marXbot, and
serves the map, the trajectory and REST control to a browser. The service's
options are in /etc/default/slamd.

The tools record simulated experiments (slam-sim), replay and evaluate them
(slam-replay, slam-evaluate), score trajectories on a benchmark's
relations (slam-relations), tune the parameters of each ray budget
(slam-tune), watch a robot link (slam-link) and load slamd (slamd-load).")
set(CPACK_DEBIAN_PACKAGE_MAINTAINER
    "Seed 87ad349d maintainers <maintainers@users.noreply.h-seed-87ad349d.example>"
    CACHE STRING "Maintainer field of the Debian package")
set(CPACK_DEBIAN_PACKAGE_SECTION science)
set(CPACK_DEBIAN_PACKAGE_PRIORITY optional)
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
set(CPACK_DEBIAN_COMPRESSION_TYPE xz)
# dpkg-shlibdeps turns the programs' libraries into Depends on Debian's runtime packages.
set(CPACK_DEBIAN_PACKAGE_SHLIBDEPS ON)
# mpirun, for `mpirun -np N slam-tune` when slam-tune links OpenMPI (its library comes through
# Depends); -DCMAKE_DISABLE_FIND_PACKAGE_MPI=ON makes a package without OpenMPI.
get_target_property(tune_libraries slam-tune LINK_LIBRARIES)
if("MPI::MPI_CXX" IN_LIST tune_libraries)
  set(CPACK_DEBIAN_PACKAGE_SUGGESTS "openmpi-bin")
endif()
set(CPACK_DEBIAN_PACKAGE_CONTROL_EXTRA
    ${CMAKE_BINARY_DIR}/packaging/conffiles ${SLAM_DEB_DIR}/postinst ${SLAM_DEB_DIR}/prerm
    ${SLAM_DEB_DIR}/postrm)
set(CPACK_DEBIAN_PACKAGE_CONTROL_STRICT_PERMISSION ON)
# Checked when cpack runs (cmake/packaging_checks.cmake): what a package must not be made
# without.
set(CPACK_SLAM_UPLOT_LICENSE_FILE ${SLAM_UPLOT_LICENSE_FILE})
set(CPACK_SLAM_COPYRIGHT_FILE ${CMAKE_BINARY_DIR}/packaging/copyright)
set(CPACK_PROJECT_CONFIG_FILE ${PROJECT_SOURCE_DIR}/cmake/packaging_checks.cmake)
include(CPack)
