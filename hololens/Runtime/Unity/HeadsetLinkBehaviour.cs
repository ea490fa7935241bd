// The Unity side of the headset link: a thin shell over the core's HeadsetSession (tested with
// mono). The session exists as soon as anything asks for it (Session), so DisplayRenderer and
// the confirm inputs work whichever component Unity starts first; Start opens the sockets;
// Update pumps the downlink and sends one gaze frame from the IEyeGazeSource on this GameObject,
// the head gaze (marked not valid) whenever the eyes are not tracked.
// Threading: everything here runs on Unity's main thread, and the core calls the clock (Unity's
// Time) and every callback there only (HeadsetLink's threading contract).
using System.Net;
using UnityEngine;

namespace FabricGuidance.Headset.Unity
{
    /// <summary>Time.realtimeSinceStartupAsDouble: monotonic; the core reads it on the main thread only.</summary>
    sealed class UnityClock : IHeadsetClock
    {
        public double Now() { return Time.realtimeSinceStartupAsDouble; }
    }

    public sealed class HeadsetLinkBehaviour : MonoBehaviour
    {
        [Tooltip("The PC running gaze_bridge and headset_display; the only sender listened to")]
        public string pcAddress = "192.168.1.10";
        [Tooltip("gaze_bridge's UDP port (its parameter 'port')")]
        public int gazePort = 5005;
        [Tooltip("This app's downlink port (the nodes' 'display_port')")]
        public int displayPort = 5006;

        HeadsetSession session;
        IEyeGazeSource eyes;

        /// <summary>The core session, made on first use (no sockets until Start).</summary>
        public HeadsetSession Session
        {
            get
            {
                if (session == null)
                    session = new HeadsetSession(IPAddress.Parse(pcAddress), gazePort, new IPEndPoint(IPAddress.Any, displayPort),
                                                 new UnityClock());
                return session;
            }
        }

        void Start()
        {
            eyes = GetComponent<IEyeGazeSource>();
            Session.Start();
        }

        void Update()
        {
            Camera main = Camera.main;
            if (main == null) return;   // no head this frame (a scene without a MainCamera tag): nothing to send
            Transform head = main.transform;
            Vector3 p = head.position;
            Quaternion q = head.rotation;
            Session.Update(eyes, new Vec3(p.x, p.y, p.z), new Quat(q.x, q.y, q.z, q.w));
        }

        /// <summary>The wearer pressed confirm (ConfirmInput calls it on a select / click).</summary>
        public void Confirm()
        {
            Session.Confirm();
        }

        void OnDestroy()
        {
            if (session != null) session.Dispose();
        }
    }
}
