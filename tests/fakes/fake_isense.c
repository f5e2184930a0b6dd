/* A stand-in for the InterSense library: ISD_OpenTracker, ISD_GetTrackingData, ISD_ResetHeading,
   ISD_CloseTracker with the isense.h 4.237 signatures and station record layout (x86-64 types.h:
   DWORD unsigned int, Bool int, WORD unsigned short, Hwnd long), driven by fake_* controls. */
#include <stddef.h>
#include <string.h>

#define ISD_MAX_STATIONS 8
#define ISD_MAX_BUTTONS 8
#define ISD_MAX_CHANNELS 10
#define ISD_MAX_AUX_INPUTS 4

typedef struct {
    unsigned char TrackingStatus, NewData, CommIntegrity, BatteryState;
    float Euler[3];
    float Quaternion[4];
    float Position[3];
    float TimeStamp, StillTime, BatteryLevel, CompassYaw;
    int ButtonState[ISD_MAX_BUTTONS];
    short AnalogData[ISD_MAX_CHANNELS];
    unsigned char AuxInputs[ISD_MAX_AUX_INPUTS];
    float AngularVelBodyFrame[3], AngularVelNavFrame[3], AccelBodyFrame[3], AccelNavFrame[3];
    float VelocityNavFrame[3], AngularVelRaw[3];
    unsigned char MeasQuality, bReserved2, bReserved3, bReserved4;
    unsigned int TimeStampSeconds, TimeStampMicroSec, OSTimeStampSeconds, OSTimeStampMicroSec;
    float Reserved[56];
    float MagBodyFrame[3];
} ISD_STATION_DATA_TYPE;

typedef struct { ISD_STATION_DATA_TYPE Station[ISD_MAX_STATIONS]; } ISD_TRACKING_DATA_TYPE;

static int present = 0, is_open = 0, opens = 0, resets = 0, fresh = 0, last_port = -1;
static int station_index = 0;
static float raw[3], yaw_offset = 0.0f, timestamp = 0.0f;
static unsigned char status = 1;

int ISD_OpenTracker(long hParent, unsigned int commPort, int infoScreen, int verbose) {
    (void)hParent; (void)infoScreen; (void)verbose;
    last_port = (int)commPort;
    if (!present) return -1;
    is_open = 1;
    opens++;
    return 1;
}
int ISD_CloseTracker(int handle) {
    if (handle != 1) return 0;
    is_open = 0;
    return 1;
}
int ISD_GetTrackingData(int handle, ISD_TRACKING_DATA_TYPE *data) {
    if (handle != 1 || !is_open || !present) return 0;
    memset(data, 0, sizeof *data);
    ISD_STATION_DATA_TYPE *s = &data->Station[station_index];
    s->TrackingStatus = status;
    s->NewData = (unsigned char)fresh;
    s->Euler[0] = raw[0] - yaw_offset;
    s->Euler[1] = raw[1];
    s->Euler[2] = raw[2];
    s->TimeStamp = timestamp;
    fresh = 0;
    return 1;
}
int ISD_ResetHeading(int handle, unsigned short stationID) {
    if (handle != 1 || stationID < 1 || stationID > ISD_MAX_STATIONS) return 0;
    yaw_offset = raw[0];
    resets++;
    return 1;
}

/* Test controls. */
void fake_plug(int yes) { present = yes; }
void fake_set_pose(int station, float yaw, float pitch, float roll, unsigned char tracking_status, float ts) {
    station_index = station - 1;
    raw[0] = yaw;
    raw[1] = pitch;
    raw[2] = roll;
    status = tracking_status;
    timestamp = ts;
    fresh = 1;
}
int fake_opens(void) { return opens; }
int fake_resets(void) { return resets; }
int fake_last_port(void) { return last_port; }
int fake_station_size(void) { return (int)sizeof(ISD_STATION_DATA_TYPE); }
int fake_offset_euler(void) { return (int)offsetof(ISD_STATION_DATA_TYPE, Euler); }
int fake_offset_timestamp(void) { return (int)offsetof(ISD_STATION_DATA_TYPE, TimeStamp); }
int fake_offset_aux(void) { return (int)offsetof(ISD_STATION_DATA_TYPE, AuxInputs); }
int fake_offset_mag(void) { return (int)offsetof(ISD_STATION_DATA_TYPE, MagBodyFrame); }
