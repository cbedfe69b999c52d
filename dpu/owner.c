/* owner.c: a run belongs to the host tool that started it. Labs are shared:
 * a second host tool on the same group must not push its configuration into a
 * run in progress, start, commit or stop anything in it. The START names its
 * sender's session; until the run ends, a config or a START/STOP/COMMIT/
 * SHUTDOWN from another session is refused, and the status says whose run it
 * is and when it ends, unless the sender forces it (`--force`), which the log
 * records. PING and RESEND change nothing and stay anyone's. */
#include <stdio.h>
#include <string.h>
#include <time.h>

#include "dpu.h"

void owner_take(skel_server_t *s, const skelmsg_command_t *start, int64_t start_utc_ns)
{
    /* The caller holds s->lock. */
    s->run_session = start->session;
    snprintf(s->run_owner, sizeof s->run_owner, "%s",
             start->sender != NULL && start->sender[0] != '\0' ? start->sender : "an unnamed host tool");
    s->run_end_utc_ns = start->duration_ns > 0 ? start_utc_ns + start->duration_ns : 0;
}

/* "until 12:34:56 UTC" or "until stopped" */
static void owner_until(int64_t end_utc_ns, char *out, size_t len)
{
    if (end_utc_ns <= 0) {
        snprintf(out, len, "until stopped");
        return;
    }
    time_t secs = (time_t)(end_utc_ns / SKEL_NS_PER_S);
    struct tm tm;
    char hms[16] = "?";
    if (gmtime_r(&secs, &tm) != NULL) (void)strftime(hms, sizeof hms, "%H:%M:%S", &tm);
    snprintf(out, len, "until %s UTC", hms);
}

/* 1 when WHAT (from SESSION/SENDER) is refused because another session's run
 * is in progress: the reason goes to the status (rejected_generation =
 * GENERATION when >= 0, so a refused push fails at once). A forced one is let
 * through and logged. */
int owner_refuses(skel_control_t *c, int64_t session, int8_t force, const char *sender,
                  const char *what, int64_t generation)
{
    skel_server_t *s = c->s;
    if (pthread_mutex_lock(&s->lock) != 0) return 1;
    int foreign = s->run_active && s->run_session != 0 && session != s->run_session;
    int64_t run_id = s->run_id, end = s->run_end_utc_ns;
    char owner[SKEL_OWNER_LEN];
    memcpy(owner, s->run_owner, sizeof owner);
    pthread_mutex_unlock(&s->lock);
    if (!foreign) return 0;
    const char *who = sender != NULL && sender[0] != '\0' ? sender : "an unnamed host tool";
    char until[40], reason[SKEL_REASON_LEN];
    owner_until(end, until, sizeof until);
    if (force) {
        /* Said in the status too: the run's owner learns who stepped in. */
        snprintf(reason, sizeof reason, "%s from %.60s forced into run %lld of %.60s (--force)", what,
                 who, (long long)run_id, owner);
        report_reject(c, -1, reason, 0);
        return 0;
    }
    snprintf(reason, sizeof reason, "%s from %.60s refused: run %lld of %.60s is in progress %s "
             "(--force takes over)", what, who, (long long)run_id, owner, until);
    report_reject(c, generation, reason, 0);
    return 1;
}
