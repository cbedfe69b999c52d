/* check.h: the C unit tests' assertion macros. Each CHECK counts one pass or
 * one failure (with file:line and the expression); CHECK_DONE prints the final
 * "N passed, M failed" line the Makefile's test runner reads and returns the
 * exit status (non-zero on any failure). */
#ifndef SKEL_CHECK_H
#define SKEL_CHECK_H

#include <stdio.h>
#include <string.h>

static int check_passed, check_failed;

#define CHECK(cond)                                                                   \
    do {                                                                              \
        if (cond) check_passed++;                                                     \
        else {                                                                        \
            check_failed++;                                                           \
            fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond);   \
        }                                                                             \
    } while (0)

#define CHECK_EQ(a, b)                                                                \
    do {                                                                              \
        long long check_a_ = (long long)(a), check_b_ = (long long)(b);               \
        if (check_a_ == check_b_) check_passed++;                                     \
        else {                                                                        \
            check_failed++;                                                           \
            fprintf(stderr, "%s:%d: CHECK_EQ failed: %s == %s (%lld != %lld)\n",       \
                    __FILE__, __LINE__, #a, #b, check_a_, check_b_);                  \
        }                                                                             \
    } while (0)

/* STR contains SUB: reasons are checked by their telling words, not verbatim. */
#define CHECK_HAS(str, sub)                                                           \
    do {                                                                              \
        const char *check_s_ = (str);                                                 \
        if (check_s_ != NULL && strstr(check_s_, (sub)) != NULL) check_passed++;       \
        else {                                                                        \
            check_failed++;                                                           \
            fprintf(stderr, "%s:%d: CHECK_HAS failed: '%s' lacks '%s'\n", __FILE__,    \
                    __LINE__, check_s_ ? check_s_ : "(null)", (sub));                 \
        }                                                                             \
    } while (0)

#define CHECK_DONE()                                                                  \
    (printf("%d passed, %d failed\n", check_passed, check_failed), check_failed != 0)

#endif
