#pragma once
// Where the files the project ships (robot descriptions, parameters, the page) are: installed
// beside the program, or in the source tree for a program run from its build folder.

#include <string>

namespace slam::io {

/// The shipped file or folder `relative` (e.g. "config/marxbot.robot.json", "web"): the installed
/// copy beside the running program (PREFIX/bin/PROGRAM -> PREFIX/share/slamd/`relative`) when it
/// exists, else the source tree's (a program run from its build folder).
std::string ShippedPath(const std::string& relative);

}  // namespace slam::io
