/* string.h - the two memory functions the firmware uses (node.c defines them): there is no libc. The packers
 * that cantools generates include <string.h>; this file answers that include (-I. in the build). */
#ifndef FW_STRING_H
#define FW_STRING_H

#include <stddef.h>

void *memset(void *s, int c, size_t n);
void *memcpy(void *restrict d, const void *restrict s, size_t n);

#endif /* FW_STRING_H */
