// divvox: interactive and headless soft-tissue cutting with Divided Voxels.
#include "app/cli.h"

int main(int argc, char** argv) { return dvx::run_cli(argc, argv); }
