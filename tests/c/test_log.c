/* test_log.c: a log line carries received strings (names, URLs, senders) but never
 * their control characters: no line is split, no terminal escape gets through. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "check.h"
#include "dpu.h"

static void test_sanitize(void)
{
    char line[] = "name\x1b[2Jx\ny\tz\x7f\r";
    log_sanitize(line);
    CHECK(strcmp(line, "name?[2Jx?y?z??") == 0);
    char c1[] = "csi \xc2\x9b" "31m, nbsp \xc2\xa0, e \xc3\xa9"; /* U+009B is a C1 control; U+00A0, U+00E9 are not */
    log_sanitize(c1);
    CHECK(strcmp(c1, "csi ??31m, nbsp \xc2\xa0, e \xc3\xa9") == 0);
    char end[] = "ends in \xc2";  /* a lone lead byte at the end: nothing read past the NUL */
    log_sanitize(end);
    CHECK(strcmp(end, "ends in \xc2") == 0);
    char clean[] = "DPU 1: staged generation 7";
    log_sanitize(clean);
    CHECK(strcmp(clean, "DPU 1: staged generation 7") == 0);
}

/* log_line itself, as a received sender would reach it (owner.c's reasons). */
static void test_log_line(void)
{
    char path[] = "/tmp/skel-test-log-XXXXXX";
    int fd = mkstemp(path);
    CHECK(fd >= 0);
    if (fd < 0) return;
    int saved = dup(STDERR_FILENO);
    CHECK(saved >= 0 && dup2(fd, STDERR_FILENO) == STDERR_FILENO);
    log_line("STOP from %s refused", "evil\n\x1b]0;owned\x07 host pid 1");
    fflush(stderr);
    CHECK(dup2(saved, STDERR_FILENO) == STDERR_FILENO);
    close(saved);
    char got[600] = "";
    ssize_t n = pread(fd, got, sizeof got - 1, 0);
    CHECK(n > 0);
    if (n > 0) got[n] = '\0';
    close(fd);
    unlink(path);
    CHECK_HAS(got, "]: STOP from evil??]0;owned? host pid 1 refused\n");
    CHECK(strchr(got, '\n') == got + strlen(got) - 1); /* one line */
}

int main(void)
{
    test_sanitize();
    test_log_line();
    return CHECK_DONE();
}
