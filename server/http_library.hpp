#pragma once
// cpp-httplib (Debian's 0.11.4), as every file of server/ includes it. <httplib.h> includes
// <resolv.h>, whose `_res` macro rewrites a parameter name of Eigen's headers included after it
// (their declarations then fail to compile); httplib's own code was expanded when included, so
// the macro goes.

#include <httplib.h>

#undef _res
