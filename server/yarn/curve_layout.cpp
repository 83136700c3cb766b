#include "server/yarn/curve_layout.h"
