"""Print the .pth line that makes .venv-launch see .venv (run with .venv's python).

site processes it after .venv-launch's own site-packages, so that venv's pytest 7.4.4 wins.
ros_wheels_bootstrapper (one of .venv's .pth files) re-executes Python with LD_LIBRARY_PATH
pointing at sys.prefix's ROS libraries, which would be .venv-launch's (none): the line puts
.venv's library directories on LD_LIBRARY_PATH first, and the re-exec keeps them.
"""
import glob
import os
import sysconfig

site = sysconfig.get_path('purelib')
libs = sorted(glob.glob(os.path.join(site, 'ros_*.libs'))) + [os.path.join(os.path.dirname(
    os.path.dirname(os.path.dirname(site))), 'lib')]
print("import os, site; os.environ.get('_ROS_WHEELS_BOOTSTRAP_COMPLETE') or "
      f"os.environ.__setitem__('LD_LIBRARY_PATH', os.pathsep.join({libs!r} + "
      "[os.environ.get('LD_LIBRARY_PATH', '')])); "
      f"site.addsitedir({site!r})")
