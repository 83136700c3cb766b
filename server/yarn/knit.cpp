#include "server/yarn/knit.h"
