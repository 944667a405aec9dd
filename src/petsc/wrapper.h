#include <petsc.h>
#include <slepceps.h>
