/* The layout table of fwlib_structs.h as numbers only, read from the compiler's assembly (gcc -S) for an ABI
 * that cannot be linked or run here (gcc -m32 without a 32-bit libc). Every value is stored plus one, so
 * none is zero and the assembler never folds a run of them into a .zero directive. A test fixture. */
#include "fwlib_structs.h"

#define N(T, name, member) offsetof(T, member) + 1, sizeof(((T *)0)->member) + 1,
#define Z(T) sizeof(T) + 1,
const unsigned int fwlib_layout_numbers[] = { FWLIB_FIELDS(N) FWLIB_STRUCTS(Z) };
