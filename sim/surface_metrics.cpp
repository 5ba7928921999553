#include "sim/surface_metrics.h"
