# Offline pose-only optimisation on SLAM keyframe matches with GT depth samples: does the
# geometry of keypoints + depth alone give a biased translation scale?
import sys, math, collections, statistics as st
sys.path.insert(0,__import__('os').path.dirname(__file__)); from png16 import read_png16
from ana_common import *
seq,out=sys.argv[1],sys.argv[2]
variant=sys.argv[3] if len(sys.argv)>3 else 'base'
stereo='stereo' in variant
kpc='kpc' in variant
cam=load_cam(seq); FX,FY,CX,CY,BF=cam
gt=load_traj(f'{seq}/groundtruth.txt')
pts=load_dump(out)
S=[1.2**i for i in range(8)]
def adj(u,v,o):
    if kpc: s=S[o]; return u+0.5*(s-1), v+0.5*(s-1)
    return u,v
# pairs
pairobs=collections.defaultdict(list)
for X,obs in pts:
    for a in obs:
        for b in obs:
            if 'lvl0' in variant and (a[3]!=0 or b[3]!=0): continue
            if 'same' in variant and a[3]!=b[3]: continue
            if a[0]<b[0] and a[4]>0: pairobs[(a[0],b[0])].append((a,b))
res=[]
nobs=[0,0]
from png16 import read_png16
_dc={}
def disc(ts,u,v,r=2):
    if ts not in _dc: _dc[ts]=read_png16(f'{seq}/depth_bg/{ts}.png')
    w,h,img=_dc[ts]; xs=[]
    for yy in range(int(v)-r,int(v)+r+1):
        for xx in range(int(u)-r,int(u)+r+1):
            if 0<=xx<w and 0<=yy<h: xs.append(img[yy*w+xx])
    return min(xs)<=0 or max(xs)>1.03*min(xs)
rot_ratio=[]
for (ta,tb),lst in pairobs.items():
    if len(lst)<40 or ta not in gt or tb not in gt: continue
    Ta=gt[ta]; Tb=gt[tb]
    # GT relative pose T_ba (camera a -> camera b): x_b = R (x_a) + t
    Rwa,Ca=Ta; Rwb,Cb=Tb
    Rba=matmul(transpose(Rwb),Rwa); tba=mtv(Rwb,[Ca[i]-Cb[i] for i in range(3)])
    tn=norm(tba)
    if tn<0.03: continue
    P=[];Z=[];W=[]
    if 'onlydisc' in variant: lst=[(a,b) for a,b in lst if disc(a[0],a[1],a[2],max(2,int(S[a[3]]+1)))]
    if len(lst)<15: continue
    if 'nodisc' in variant: lst=[(a,b) for a,b in lst if not disc(a[0],a[1],a[2],max(2,int(S[a[3]]+1)))]
    for a,b in lst:
        ua,va=adj(a[1],a[2],a[3]); da=a[4]
        P.append([(ua-CX)/FX*da,(va-CY)/FY*da,da])
        ub,vb=adj(b[1],b[2],b[3])
        Z.append((ub,vb,(ub-BF/b[4]) if (stereo and b[4]>0) else None)); W.append(1.0/S[b[3]]**2)
    if 'sim' in variant:
        import random
        rnd=random.Random(hash((ta,tb))&0xffff)
        sig=float(variant.split('sim')[1].split('_')[0] or 1.0)
        Z2=[];P2=[]
        for (a,b),X,z in zip(lst,P,Z):
            x=[p+q for p,q in zip(mv(Rba,X),tba)]
            sb=S[b[3]]*sig; sa=S[a[3]]*sig
            Z2.append((FX*x[0]/x[2]+CX+rnd.gauss(0,sb), FY*x[1]/x[2]+CY+rnd.gauss(0,sb), None))
            if 'noisya' in variant:
                d=X[2]; P2.append([X[0]+rnd.gauss(0,sa)*d/FX, X[1]+rnd.gauss(0,sa)*d/FY, d])
            else: P2.append(X)
        Z=Z2; P=P2
    if 'gtobs' in variant:
        Z2=[]
        for X,z in zip(P,Z):
            x=[a+b for a,b in zip(mv(Rba,X),tba)]
            Z2.append((FX*x[0]/x[2]+CX, FY*x[1]/x[2]+CY, None))
        Z=Z2
    R,t,ninl=pose_opt(P,Z,W,Rba,tba,cam,fixrot='fixrot' in variant)
    def ang(R): return math.acos(max(-1,min(1,(R[0][0]+R[1][1]+R[2][2]-1)/2)))
    rot_ratio.append((ang(Rba), ang(R)/max(ang(Rba),1e-9)))
    res.append((tn, dot([t[i]-tba[i] for i in range(3)],tba)/tn/tn, norm(t)/tn, ninl, len(lst)))
print('%s: %d keyframe pairs; translation along GT direction, mean relative error %.5f (median %.5f); |t_est|/|t_gt| weighted by |t_gt|: %.5f'%(variant,len(res),st.mean(r[1] for r in res),st.median(r[1] for r in res), sum(r[2]*r[0] for r in res)/sum(r[0] for r in res)))
print('   rotation angle est/gt weighted: %.5f (mean gt angle %.2f deg)'%(sum(a*r for a,r in rot_ratio)/sum(a for a,r in rot_ratio), math.degrees(st.mean(a for a,r in rot_ratio))))
