/* A stand-in for ViewPoint's VPX_InterApp library: the SDK entry points fovjax uses, with the
   signatures of the SDK header, backed by state the test sets through fake_* functions. */
#include <pthread.h>

typedef struct { float x, y; } VPX_RealPoint;
typedef int (*VPX_CALLBACK)(int msg, int subMsg, int param1, int param2, void *userPtr);

static VPX_CALLBACK callback_fn = 0;
static void *callback_user = 0;
static VPX_RealPoint gaze[2];
static VPX_RealPoint smoothed_gaze[2]; /* what ViewPoint's smoothing filter would give */
static int quality[2] = {5, 5};
static double data_time[2];

int VPX_GetGazePoint2(int eye, VPX_RealPoint *gp) {
    if (eye < 0 || eye > 1) return 0;
    *gp = gaze[eye];
    return 1;
}
int VPX_GetGazePointSmoothed2(int eye, VPX_RealPoint *gp) {
    if (eye < 0 || eye > 1) return 0;
    *gp = smoothed_gaze[eye];
    return 1;
}
int VPX_GetDataQuality2(int eye, int *q) {
    if (eye < 0 || eye > 1) return 0;
    *q = quality[eye];
    return 1;
}
int VPX_GetDataTime2(int eye, double *t) {
    if (eye < 0 || eye > 1) return 0;
    *t = data_time[eye];
    return 1;
}
int VPX_InsertCallback(VPX_CALLBACK fn, void *user) {
    callback_fn = fn;
    callback_user = user;
    return 1;
}
int VPX_RemoveCallback(VPX_CALLBACK fn) {
    if (callback_fn == fn) callback_fn = 0;
    return 1;
}

/* Test controls. */
void fake_set_eye(int eye, float x, float y, int q, double t) {
    gaze[eye].x = x;
    gaze[eye].y = y;
    smoothed_gaze[eye] = gaze[eye];
    quality[eye] = q;
    data_time[eye] = t;
}
/* A smoothed point apart from the raw one (set after fake_set_eye). */
void fake_set_smoothed(int eye, float x, float y) {
    smoothed_gaze[eye].x = x;
    smoothed_gaze[eye].y = y;
}
int fake_fire(int msg, int sub_msg) { return callback_fn ? callback_fn(msg, sub_msg, 0, 0, callback_user) : -1; }
int fake_callback_registered(void) { return callback_fn != 0; }

static void *fire_thread(void *arg) {
    int *msg = (int *)arg;
    fake_fire(msg[0], msg[1]);
    return 0;
}
/* Fire the callback from a thread the interpreter did not create, as ViewPoint does. */
int fake_fire_from_thread(int msg, int sub_msg) {
    pthread_t thread;
    int args[2] = {msg, sub_msg};
    if (pthread_create(&thread, 0, fire_thread, args) != 0) return -1;
    pthread_join(thread, 0);
    return 0;
}
