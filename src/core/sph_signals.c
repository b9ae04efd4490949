/* Requests to stop: SIGTERM before a kill and SIGUSR1 as a warning (batch schedulers), and
 * SIGINT (Ctrl-C at a terminal): the handler only records the signal; the run loop polls it
 * after each step, writes a checkpoint and stops cleanly (sph_signals.f90). A second SIGINT
 * ends the program at once (the handler is reset after the first), as users expect of a
 * second Ctrl-C. */
#include <signal.h>
#include <string.h>

static volatile sig_atomic_t sph_received = 0;

static void sph_record(int signum) { sph_received = signum; }

/* Install the handlers for SIGTERM, SIGUSR1 and SIGINT; 0 on success. */
int sph_signals_install(void)
{
    struct sigaction action;
    memset(&action, 0, sizeof action);
    action.sa_handler = sph_record;
    sigemptyset(&action.sa_mask);
    action.sa_flags = SA_RESTART;
    if (sigaction(SIGTERM, &action, NULL) != 0) return 1;
    if (sigaction(SIGUSR1, &action, NULL) != 0) return 1;
    action.sa_flags = SA_RESTART | SA_RESETHAND;
    if (sigaction(SIGINT, &action, NULL) != 0) return 1;
    return 0;
}

/* The last signal received (0: none). */
int sph_signal_received(void) { return (int)sph_received; }

/* The name of one of the signals handled ("" for another number). */
const char *sph_signal_name(int signum)
{
    if (signum == SIGTERM) return "SIGTERM";
    if (signum == SIGUSR1) return "SIGUSR1";
    if (signum == SIGINT) return "SIGINT";
    return "";
}
