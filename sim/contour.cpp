#include "sim/contour.h"
