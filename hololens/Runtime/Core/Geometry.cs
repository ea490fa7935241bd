// Plain value types for positions and rotations, so that the core has no UnityEngine
// dependency; the Unity layer converts Vector3 / Quaternion to these at the boundary.
namespace FabricGuidance.Headset
{
    /// <summary>A point or direction in Unity's world frame (left-handed, y up), metres.</summary>
    public struct Vec3
    {
        public double X, Y, Z;
        public Vec3(double x, double y, double z) { X = x; Y = y; Z = z; }
        public bool IsFinite { get { return Finite(X) && Finite(Y) && Finite(Z); } }
        internal static bool Finite(double v) { return !double.IsNaN(v) && !double.IsInfinity(v); }
        public override string ToString() { return "(" + Json.Number(X) + ", " + Json.Number(Y) + ", " + Json.Number(Z) + ")"; }
    }

    /// <summary>A rotation in Unity's component order (x, y, z, w).</summary>
    public struct Quat
    {
        public double X, Y, Z, W;
        public Quat(double x, double y, double z, double w) { X = x; Y = y; Z = z; W = w; }
        public bool IsFinite { get { return Vec3.Finite(X) && Vec3.Finite(Y) && Vec3.Finite(Z) && Vec3.Finite(W); } }
    }
}
