#include "sim/voxel_model.h"
