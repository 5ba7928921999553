#include "sim/mesh_distance.h"
