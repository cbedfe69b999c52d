/* log.c: one concise line per event on stderr, prefixed so that several DPUs
 * sharing a terminal (or a test's captured stderr) can be told apart. */
#include <stdarg.h>
#include <stdio.h>
#include <unistd.h>

#include "dpu.h"

/* Received strings reach these lines (a config's names and URLs, a sender, a reason
 * built from them): a control character in one would split the line or drive the
 * terminal (an ESC sequence), so each C0 control, DEL and UTF-8-encoded C1 control
 * (U+0080..U+009F, which some terminals also obey) becomes '?'. In place. */
void log_sanitize(char *line)
{
    for (unsigned char *p = (unsigned char *)line; *p != '\0'; p++) {
        if (*p < 0x20 || *p == 0x7f) *p = '?';
        else if (*p == 0xc2 && p[1] >= 0x80 && p[1] <= 0x9f) {
            p[0] = p[1] = '?';
            p++;
        }
    }
}

void log_line(const char *fmt, ...)
{
    char line[512];
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(line, sizeof line, fmt, ap);
    va_end(ap);
    if (n < 0) return;
    log_sanitize(line);
    /* One fprintf per line keeps lines whole when both threads log. */
    fprintf(stderr, "skel-dpu[%d]: %s\n", (int)getpid(), line);
}
