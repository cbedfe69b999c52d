/* log.c: one concise line per event on stderr, prefixed so that several DPUs
 * sharing a terminal (or a test's captured stderr) can be told apart. */
#include <stdarg.h>
#include <stdio.h>
#include <unistd.h>

#include "dpu.h"

void log_line(const char *fmt, ...)
{
    char line[512];
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(line, sizeof line, fmt, ap);
    va_end(ap);
    if (n < 0) return;
    /* One fprintf per line keeps lines whole when both threads log. */
    fprintf(stderr, "skel-dpu[%d]: %s\n", (int)getpid(), line);
}
