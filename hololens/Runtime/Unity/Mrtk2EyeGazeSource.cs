// MRTK 2: CoreServices.InputSystem.EyeGazeProvider (eye tracking enabled in the MRTK input
// profile's pointer settings, the "OpenXR XRSDK Eye Gaze Provider" data provider on Unity
// 2021.2 and later). Its gaze is in Unity world. The eyes count only while MRTK uses them for
// gaze and the wearer's eye calibration is valid (null: not known yet); otherwise the core sends
// the head gaze marked not valid.
#if FG_MRTK2
using Microsoft.MixedReality.Toolkit;
using UnityEngine;

namespace FabricGuidance.Headset.Unity
{
    public sealed class Mrtk2EyeGazeSource : MonoBehaviour, IEyeGazeSource
    {
        public bool TryGetEyeGaze(out Vec3 origin, out Vec3 direction)
        {
            origin = direction = default(Vec3);
            var eye = CoreServices.InputSystem?.EyeGazeProvider;
            if (eye == null || !eye.IsEyeTrackingEnabledAndValid || eye.IsEyeCalibrationValid != true) return false;
            Vector3 o = eye.GazeOrigin, d = eye.GazeDirection;
            origin = new Vec3(o.x, o.y, o.z);
            direction = new Vec3(d.x, d.y, d.z);
            return true;
        }
    }
}
#endif
