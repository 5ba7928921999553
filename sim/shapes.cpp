#include "sim/shapes.h"
