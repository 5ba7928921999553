#include "sim/voxelize.h"
